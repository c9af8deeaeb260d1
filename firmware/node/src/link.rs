//! The board's CAN device and clocks, chosen by feature: SLCAN on USART1 under QEMU, bxCAN1 on a
//! board. Everything else in the node sees only `embedded_can::nb::Can`.

use dex_runtime::can::CanFrame;
use embedded_can::Error as _;
use heapless::spsc::Producer;
use stm32f4xx_hal::pac::{CAN1, GPIOA, GPIOB, RCC, USART1};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::{Config, Rcc};

use crate::counters::Counters;
use crate::event::Event;

/// GPIO ports the link's pins live on.
pub struct Pins {
    /// Port A (USART1 TX PA9, RX PA10).
    pub gpioa: GPIOA,
    /// Port B (CAN1 RX PB8, TX PB9).
    pub gpiob: GPIOB,
}

/// The peripherals a link may take.
pub struct Devices {
    /// USART1 (the SLCAN line under QEMU: QEMU's first `-serial`).
    pub usart1: USART1,
    /// CAN1 (bxCAN, the board's transceiver).
    pub can1: CAN1,
}

/// The QEMU link: SLCAN on USART1.
#[cfg(feature = "qemu")]
pub type Link = crate::slcan_can::SlcanCan<stm32f4xx_hal::serial::Serial<USART1>>;

/// The board link: bxCAN1 through the `bxcan` driver.
#[cfg(not(feature = "qemu"))]
pub type Link = bxcan::Can<stm32f4xx_hal::can::Can<CAN1>>;

/// Clocks. QEMU models no RCC (its registers read 0), so the QEMU build stays on the 16 MHz HSI
/// the core starts on; the board runs from an 8 MHz crystal (Nucleo-F4 ST-LINK MCO, Discovery
/// F4) at 168 MHz, APB1 42 MHz.
pub fn clocks(rcc: RCC) -> Rcc {
    if cfg!(feature = "qemu") {
        rcc.freeze(Config::hsi())
    } else {
        rcc.freeze(
            Config::hse(8.MHz())
                .sysclk(168.MHz())
                .pclk1(42.MHz())
                .pclk2(84.MHz()),
        )
    }
}

/// Opens the link.
#[cfg(feature = "qemu")]
pub fn open(pins: Pins, devices: Devices, rcc: &mut Rcc) -> Link {
    use stm32f4xx_hal::serial::{Config as SerialConfig, Event as SerialEvent, Serial};
    use stm32f4xx_hal::time::U32Ext as _;
    let _ = devices.can1;
    let _ = pins.gpiob;
    let gpioa = pins.gpioa.split(rcc);
    let cfg = SerialConfig::default().baudrate(115_200.bps());
    match Serial::new(devices.usart1, (gpioa.pa9, gpioa.pa10), cfg, rcc) {
        Ok(mut serial) => {
            serial.listen(SerialEvent::RxNotEmpty);
            crate::slcan_can::SlcanCan::new(serial)
        }
        Err(_) => crate::node::fatal("USART1 configuration"),
    }
}

/// Opens the link: bxCAN1 on PB8/PB9 at 500 kbit/s (APB1 42 MHz: prescaler 6, 14 time quanta,
/// sample point 85.7 %), every identifier into FIFO 0, its message-pending interrupt on.
#[cfg(not(feature = "qemu"))]
pub fn open(pins: Pins, devices: Devices, rcc: &mut Rcc) -> Link {
    let _ = devices.usart1;
    let _ = pins.gpioa;
    let gpiob = pins.gpiob.split(rcc);
    let can = devices.can1.can((gpiob.pb9, gpiob.pb8), rcc);
    let mut can = bxcan::Can::builder(can)
        .set_bit_timing(0x001a_0005)
        .leave_disabled();
    can.modify_filters()
        .enable_bank(0, bxcan::Fifo::Fifo0, bxcan::filter::Mask32::accept_all());
    can.enable_interrupt(bxcan::Interrupt::Fifo0MessagePending);
    if nb::block!(can.enable_non_blocking()).is_err() {
        crate::node::fatal("bxCAN enable");
    }
    can
}

/// The Lawicel time stamp of the frame just received (only SLCAN lines carry one).
fn stamp(link: &Link) -> Option<u16> {
    #[cfg(feature = "qemu")]
    {
        link.last_stamp()
    }
    #[cfg(not(feature = "qemu"))]
    {
        let _ = link;
        None
    }
}

/// Reads every waiting frame into the queue (receive interrupt); counts overruns, line errors
/// and frames the full queue drops.
pub fn drain(link: &mut Link, producer: &mut Producer<'static, Event>, counters: &Counters) {
    // Bounded: at most this many reads per interrupt, so a babbling line cannot hold the CPU.
    for _ in 0..256 {
        match embedded_can::nb::Can::receive(link) {
            Ok(frame) => {
                let Some(frame) = CanFrame::from_frame(&frame) else {
                    counters.bad_lines.bump();
                    continue;
                };
                if producer.enqueue(Event::Frame(frame, stamp(link))).is_err() {
                    counters.queue_full.bump();
                }
            }
            Err(nb::Error::WouldBlock) => return,
            Err(nb::Error::Other(e)) => match e.kind() {
                embedded_can::ErrorKind::Overrun => counters.overruns.bump(),
                _ if cfg!(feature = "qemu") => count_slcan(e, counters),
                _ => counters.line_errors.bump(),
            },
        }
    }
}

#[cfg(feature = "qemu")]
fn count_slcan(e: crate::slcan_can::SlcanLinkError, counters: &Counters) {
    // Bad lines were counted where they were parsed.
    if e == crate::slcan_can::SlcanLinkError::Line {
        counters.line_errors.bump();
    }
}

#[cfg(not(feature = "qemu"))]
fn count_slcan<E>(_: E, counters: &Counters) {
    counters.line_errors.bump();
}

/// Transmits a frame, waiting for a free mailbox (bxCAN) or the USART.
pub fn transmit(link: &mut Link, frame: &CanFrame) -> bool {
    #[cfg(feature = "qemu")]
    let f = *frame;
    #[cfg(not(feature = "qemu"))]
    let Some(f) = <bxcan::Frame as embedded_can::Frame>::new(
        embedded_can::Frame::id(frame),
        embedded_can::Frame::data(frame),
    ) else {
        return false;
    };
    nb::block!(embedded_can::nb::Can::transmit(link, &f)).is_ok()
}

//! `dex-node`: the runtime's controller as a CAN node on an STM32F405, on RTIC 2 and
//! stm32f4xx-hal.
//!
//! - **CAN**: one `embedded_can::nb::Can` device: bxCAN1 through the `bxcan` driver (feature
//!   `board`), or [`slcan_can::SlcanCan`], SLCAN lines on USART1 (feature `qemu`: QEMU models the
//!   STM32F4's USARTs but no CAN controller).
//! - **Control period**: TIM2's update interrupt (priority 3, the highest) every
//!   `ControllerConfig::period_us`; it only counts and pends the control task, so no amount of
//!   received traffic can delay it. Under QEMU the period is not calibrated (QEMU models no RCC
//!   and runs its STM32 timer model from its own clock): lockstep runs take time from the bus
//!   instead (`bus_time`).
//! - **Receive**: the device's interrupt (priority 2: USART1 RXNE or CAN1 FIFO 0 pending) reads
//!   every waiting frame into a bounded queue; a full queue drops the frame and counts it.
//! - **Control task** (priority 1, bound to the otherwise unused EXTI0 vector, pended by the two
//!   above): drains the queue into `Controller::on_frame_slots`, polls the controller once per
//!   timer period (or, on bus time, on every CANopen SYNC), transmits what comes back, mirrors
//!   the slot regions into NorFlash at commit points and logs a status line when a count
//!   changes.
//!
//! No heap; every buffer is static and bounded. Logs go over semihosting.
#![no_std]
#![no_main]

mod bus_time;
mod counters;
mod event;
mod flash;
mod link;
mod node;
mod regions;
#[cfg(feature = "qemu")]
mod slcan_can;
#[cfg(feature = "qemu")]
mod slcan_rx;
mod watchdog;

use panic_semihosting as _;

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use heapless::spsc::{Consumer, Producer, Queue};
    use stm32f4xx_hal::pac::{Interrupt, TIM2};
    use stm32f4xx_hal::prelude::*;
    use stm32f4xx_hal::timer::{CounterUs, Event as TimerEvent};

    use crate::counters::COUNTERS;
    use crate::event::Event;
    use crate::link::Link;
    use crate::node::Node;

    /// Depth of the receive queue (frames between two runs of the control task).
    pub const QUEUE: usize = 64;

    #[shared]
    struct Shared {
        link: Link,
        producer: Producer<'static, Event>,
    }

    #[local]
    struct Local {
        timer: CounterUs<TIM2>,
        consumer: Consumer<'static, Event>,
        node: Node,
    }

    #[init(local = [queue: Queue<Event, QUEUE> = Queue::new()])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp = cx.device;
        let mut rcc = crate::link::clocks(dp.RCC);
        let link = crate::link::open(
            crate::link::Pins {
                gpioa: dp.GPIOA,
                gpiob: dp.GPIOB,
            },
            crate::link::Devices {
                usart1: dp.USART1,
                can1: dp.CAN1,
            },
            &mut rcc,
        );
        let node = Node::boot(dp.FLASH, crate::watchdog::Dog::start(dp.IWDG));
        let mut timer = dp.TIM2.counter_us(&mut rcc);
        if timer.start(node.period_us().micros()).is_err() {
            crate::node::log(format_args!("FAULT timer start"));
        }
        timer.listen(TimerEvent::Update);
        let (producer, consumer) = cx.local.queue.split();
        rtic::pend(Interrupt::EXTI0);
        (
            Shared { link, producer },
            Local {
                timer,
                consumer,
                node,
            },
        )
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// The control period: count it and wake the control task.
    #[task(binds = TIM2, priority = 3, local = [timer])]
    fn tick(cx: tick::Context) {
        cx.local.timer.clear_all_flags();
        COUNTERS.ticks.bump();
        rtic::pend(Interrupt::EXTI0);
    }

    /// Received frames into the queue: SLCAN bytes on USART1 (QEMU; never pended on a board).
    #[task(binds = USART1, priority = 2, shared = [link, producer])]
    fn usart_rx(cx: usart_rx::Context) {
        receive(cx.shared.link, cx.shared.producer);
    }

    /// Received frames into the queue: bxCAN1 FIFO 0 (board; never pended under QEMU).
    #[task(binds = CAN1_RX0, priority = 2, shared = [link, producer])]
    fn can_rx(cx: can_rx::Context) {
        receive(cx.shared.link, cx.shared.producer);
    }

    fn receive(
        mut link: impl rtic::Mutex<T = Link>,
        mut producer: impl rtic::Mutex<T = Producer<'static, Event>>,
    ) {
        producer.lock(|p| link.lock(|l| crate::link::drain(l, p, &COUNTERS)));
        rtic::pend(Interrupt::EXTI0);
    }

    /// The controller.
    #[task(binds = EXTI0, priority = 1, shared = [link], local = [consumer, node])]
    fn control(mut cx: control::Context) {
        let node = cx.local.node;
        let consumer = cx.local.consumer;
        node.run(consumer, &mut cx.shared.link, &COUNTERS);
    }
}

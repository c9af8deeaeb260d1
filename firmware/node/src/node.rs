//! The node: the runtime's [`Controller`] over the A/B slots, fed from the receive queue, polled
//! by the timer (or by SYNC on bus time), its slots mirrored into NorFlash, its counts logged.

use core::fmt::{self, Write as _};

use cortex_m_semihosting::hio;
use dex_runtime::can::CanFrame;
use dex_runtime::{Clock, Controller, ControllerConfig, Outbox, PolicySlots};
use heapless::spsc::Consumer;
use rtic::Mutex;

use crate::bus_time::NodeClock;
use crate::counters::Counters;
use crate::event::Event;
use crate::flash::MirrorFlash;
use crate::link::Link;
use crate::watchdog::Dog;
use dex_slot_mirror::SlotMirror;

/// Widest layer the node accepts (the host controller node's width).
pub const WIDTH: usize = 256;
/// CANopen SYNC: on bus time, the control period's tick.
const SYNC_ID: u16 = 0x080;
/// Least timer periods between two status lines.
const STATUS_TICKS: u32 = 20;

/// Writes one line over semihosting. On a board only with a debugger attached: semihosting's
/// breakpoint without one would be a HardFault. (QEMU serves semihosting itself.)
pub fn log(args: fmt::Arguments<'_>) {
    if !cfg!(feature = "qemu") && !cortex_m::peripheral::DCB::is_debugger_attached() {
        return;
    }
    if let Ok(mut out) = hio::hstdout() {
        let _ = out.write_fmt(args);
        let _ = out.write_str("\n");
    }
}

/// Logs `what` and stops: a configuration the node cannot run without.
pub fn fatal(what: &str) -> ! {
    log(format_args!("FAULT {what}"));
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

/// What the slots were at the last mirror: (active slot, its CRC).
type Committed = (Option<usize>, u32);

/// The controller node.
pub struct Node {
    controller: Controller<'static, WIDTH>,
    slots: Option<PolicySlots<'static>>,
    mirror: SlotMirror<MirrorFlash>,
    clock: NodeClock,
    cfg: ControllerConfig,
    ticks_seen: u32,
    dropped_seen: u32,
    frames_seen: u32,
    status_tick: u32,
    committed: Committed,
    dog: Dog,
}

impl Node {
    /// Boot: mirror -> regions, mount, attach the active slot if there is one.
    pub fn boot(flash: stm32f4xx_hal::pac::FLASH, dog: Dog) -> Self {
        let Some(mut mirror) = crate::flash::mirror(flash) else {
            fatal("flash taken twice")
        };
        let Some((a, b)) = crate::regions::take() else {
            fatal("regions taken twice")
        };
        if mirror.load([&mut *a, &mut *b]).is_err() {
            fatal("slot mirror unreadable");
        }
        let slots = match PolicySlots::mount(a, b) {
            Ok(s) => s,
            Err(_) => fatal("slot regions misaligned"),
        };
        let cfg = ControllerConfig::default();
        let mut controller = Controller::<'static, WIDTH>::new(cfg);
        if slots.active().is_some() && controller.attach_slots(&slots).is_err() {
            log(format_args!("BOOT stored policy refused"));
        }
        let committed = (slots.active_index(), slots.active_crc());
        log(format_args!(
            "BOOT dex-node node=0x{:02x} slot_capacity={} active={:?} crc=0x{:08x}",
            cfg.node_id,
            slots.capacity(),
            committed.0,
            committed.1
        ));
        Node {
            controller,
            slots: Some(slots),
            mirror,
            clock: NodeClock::new(),
            cfg,
            ticks_seen: 0,
            dropped_seen: 0,
            frames_seen: 0,
            status_tick: 0,
            committed,
            dog,
        }
    }

    /// The control period in microseconds.
    pub fn period_us(&self) -> u32 {
        self.cfg.period_us
    }

    /// One run of the control task: timer periods first, then every queued frame.
    pub fn run(
        &mut self,
        consumer: &mut Consumer<'static, Event>,
        link: &mut impl Mutex<T = Link>,
        counters: &Counters,
    ) {
        let Some(mut slots) = self.slots.take() else {
            fatal("slots lost");
        };
        // Timer periods since the last run: one poll, the clock advanced by all of them (a late
        // run counts as missed cycles in the controller, as the host node's real-time loop does).
        let ticks = counters.ticks.get();
        let periods = ticks.wrapping_sub(self.ticks_seen);
        self.ticks_seen = ticks;
        if periods > 0 {
            self.dog.feed();
            if !self.clock.is_bus_time() {
                self.clock.on_ticks(periods, self.cfg.period_us);
                let out = self.controller.poll_slots(&self.clock, &mut slots);
                send(link, &out, counters);
            }
        }
        while let Some(event) = consumer.dequeue() {
            let Event::Frame(frame, stamp) = event;
            counters.frames_in.bump();
            if let Some(ms) = stamp
                && self.clock.on_stamp(ms)
            {
                self.restart_on_bus_time(&slots);
            }
            let out = if self.clock.is_bus_time() && frame.standard_id() == Some(SYNC_ID) {
                self.controller.poll_slots(&self.clock, &mut slots)
            } else {
                self.controller
                    .on_frame_slots(&frame, &self.clock, &mut slots)
            };
            send(link, &out, counters);
        }
        self.slots = Some(self.commit(slots, counters));
        self.status(counters);
    }

    /// The first time-stamped frame: the bus (a lockstep simulation) owns time from now on. The
    /// controller starts afresh on the bus's clock, as a node powered on at that bus time
    /// would (the periods the timer drove before are forgotten), with the active slot.
    fn restart_on_bus_time(&mut self, slots: &PolicySlots<'static>) {
        self.controller = Controller::<'static, WIDTH>::new(self.cfg);
        if slots.active().is_some() && self.controller.attach_slots(slots).is_err() {
            log(format_args!("BUSTIME stored policy refused"));
        }
        log(format_args!(
            "BUSTIME controller restarted at {} us",
            self.clock.now_us()
        ));
    }

    /// Mirrors the regions into NorFlash when a new policy became active and settled (no
    /// transfer running, not on trial): the slots are unmounted, synced and mounted again, as
    /// after a reset, which keeps the active slot (the highest valid generation).
    fn commit(&mut self, slots: PolicySlots<'static>, counters: &Counters) -> PolicySlots<'static> {
        let now = (slots.active_index(), slots.active_crc());
        if now == self.committed || slots.transfer_state() != 0 || slots.on_trial() {
            return slots;
        }
        let (a, b) = slots.into_regions();
        for (k, region) in [&*a, &*b].into_iter().enumerate() {
            match self.mirror.sync(k, region) {
                Ok(true) => counters.flash_writes.bump(),
                Ok(false) => {}
                Err(_) => counters.flash_errors.bump(),
            }
        }
        let slots = match PolicySlots::mount(a, b) {
            Ok(s) => s,
            Err(_) => fatal("slot regions misaligned"),
        };
        self.committed = (slots.active_index(), slots.active_crc());
        log(format_args!(
            "COMMIT active={:?} crc=0x{:08x}",
            self.committed.0, self.committed.1
        ));
        slots
    }

    /// A status line when something was dropped or frames came in since the last one, at most
    /// one every [`STATUS_TICKS`] timer periods: a flood of bad input cannot turn into a flood of
    /// (slow) log writes.
    fn status(&mut self, counters: &Counters) {
        let dropped = counters.dropped();
        let ticks = counters.ticks.get();
        let frames = counters.frames_in.get();
        let changed = dropped != self.dropped_seen || frames != self.frames_seen;
        if !changed || ticks.wrapping_sub(self.status_tick) < STATUS_TICKS {
            return;
        }
        self.dropped_seen = dropped;
        self.status_tick = ticks;
        self.frames_seen = frames;
        self.log_status(counters);
    }

    /// The status object: the link's counts and the controller's diagnostics.
    pub fn log_status(&self, counters: &Counters) {
        let d = self.controller.diagnostics();
        log(format_args!(
            "STATUS state={:?} fault={:?} {} cycles={} evaluations={} e2e_errors={} \
             incomplete_observations={} ignored_frames={}",
            self.controller.state(),
            self.controller.fault(),
            counters,
            d.cycles,
            d.evaluations,
            d.e2e_errors,
            d.incomplete_observations,
            d.ignored_frames
        ));
    }
}

fn send(link: &mut impl Mutex<T = Link>, out: &Outbox, counters: &Counters) {
    for f in out {
        let f: &CanFrame = f;
        if link.lock(|l| crate::link::transmit(l, f)) {
            counters.frames_out.bump();
        }
    }
}

//! The run: one controller and the reference model driven in lockstep, a frame, a poll or a load at
//! a time; each step ends in [`Run::step`] (see [`super::checks`]).

use dex_policy::PolicyView;
use dex_runtime::can::CanFrame;
use dex_runtime::can::messages::{ACTION_FRAMES, NMT_ID, NmtCommand, OBS_FRAMES, rpdo_cob_id};
use dex_runtime::controller::PolicyInfo;
use dex_runtime::{Clock, Controller, LoadError, Mlp, MockClock, Outbox, State};
use embedded_can::Frame;

use super::WIDTH;
use super::checks::Event;
use super::model::{ActivePolicy, Model};
use super::stats;

/// The controller under test, the reference model and the clock they share, with the alive counters
/// the controller's next protected frames must carry.
pub(crate) struct Run<'p> {
    pub(crate) controller: Controller<'p, WIDTH>,
    pub(crate) model: Model<'p>,
    pub(crate) clock: MockClock,
    /// Next alive counter per protected identifier the controller sends.
    pub(crate) tx_action: [u8; ACTION_FRAMES],
    pub(crate) tx_emcy: u8,
    pub(crate) tx_info: u8,
    pub(crate) tx_status: u8,
}

impl<'p> Run<'p> {
    pub(crate) fn deliver(&mut self, frame: CanFrame) {
        let now = self.clock.now_us();
        let id = frame.standard_id().expect("standard");
        let event = if id == NMT_ID {
            Event::Nmt(frame.data().first().and_then(|&c| NmtCommand::from_code(c)))
        } else if (0..OBS_FRAMES).any(|k| rpdo_cob_id(self.model.cfg.node_id, k) == id) {
            Event::Observation
        } else {
            Event::Other
        };
        // An NMT frame for another node or of 0-1 bytes changes nothing; treat it as "other".
        let event = match event {
            Event::Nmt(_)
                if frame.data().len() < 2
                    || (frame.data()[1] != 0 && frame.data()[1] != self.model.cfg.node_id) =>
            {
                Event::Other
            }
            e => e,
        };
        if let Event::Nmt(Some(NmtCommand::ResetCommunication)) = event {
            self.tx_action = [0; ACTION_FRAMES];
            self.tx_emcy = 0;
            self.tx_info = 0;
            self.tx_status = 0;
        }
        let nibble =
            (event == Event::Observation && frame.data().len() >= 2).then(|| frame.data()[1] >> 4);
        let before = self.controller.state();
        self.model.frame(&frame, now);
        let out = self.controller.on_frame(&frame, &self.clock);
        self.step(event, before, nibble, out);
    }

    pub(crate) fn poll(&mut self) {
        let now = self.clock.now_us();
        let before = self.controller.state();
        self.model.poll(now);
        let out = self.controller.poll(&self.clock);
        self.step(Event::Poll, before, None, out);
    }

    /// `load_policy` on both; checks invariant 7.
    pub(crate) fn load(&mut self, view: &PolicyView<'p>, must_load: bool) {
        let before = self.controller.state();
        let info_before = self.controller.policy_info();
        let result = self.controller.load_policy(view);
        if self.model.state == State::Operational {
            assert!(
                matches!(result, Err(LoadError::Operational)),
                "load while operational: {result:?}"
            );
        } else {
            assert_eq!(result.is_ok(), must_load, "load result {result:?}");
        }
        stats::count(if result.is_ok() { 6 } else { 7 });
        match result {
            Ok(()) => {
                let mlp = Mlp::new(view).expect("a file the controller took evaluates");
                self.model.policy = Some(ActivePolicy {
                    mlp,
                    info: PolicyInfo {
                        layout_hash: view.header().layout_hash,
                        format_version: view.header().version,
                        task: view.body().task as u8,
                    },
                });
                self.model.announce = true;
            }
            Err(_) => assert_eq!(
                self.controller.policy_info(),
                info_before,
                "a refused load changed the policy"
            ),
        }
        self.step(Event::Load, before, None, Outbox::new());
    }
}

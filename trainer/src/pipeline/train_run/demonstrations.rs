//! The demonstrations of a seed's run: given files, or episodes recorded into the seed folder.

use super::*;

/// The demonstration buffer of a seed's run: the settings' files, or `record_demos` episodes of
/// the Markov demonstrator recorded into the seed's folder (`demos.dxdm`, reused when there).
pub(super) fn demonstrations(
    s: &TrainSettings,
    seed: u64,
    dir: &Path,
    scene: &Scene,
    on_event: &mut dyn FnMut(TrainEvent<'_>),
) -> Result<Option<DemoBuffer>, TrainRunError> {
    use crate::files::demos::{DEMO_SEED, DemoSet, RecordSettings, demo_buffer, record_with};
    if !s.run.demos.uses_demos() {
        return Ok(None);
    }
    let env_cfg = s.reward.env_config(s.task.task());
    let mut sets = Vec::new();
    for path in &s.demo_files {
        sets.push((DemoSet::load(path)?, path.clone()));
    }
    if sets.is_empty() {
        let path = dir.join("demos.dxdm");
        let want = RecordSettings {
            episodes: s.record_demos,
            seed: DEMO_SEED + 500_000 + seed,
            arm_noise: s.demo_noise,
            finger_noise: 0.5 * s.demo_noise,
            reward: Some(env_cfg.reward),
            ..RecordSettings::new(s.task.task())
        };
        let set = match DemoSet::load(&path) {
            Ok(set) if set.header.settings == want => set,
            _ => {
                on_event(TrainEvent::RecordingDemos {
                    seed,
                    episodes: want.episodes,
                    path: &path,
                });
                let source = DemoSource::Markov(crate::env::MarkovDemonstrator::new(s.task.task()));
                let set = record_with(scene, None, &source, &want, &|| {})?;
                set.save(&path)?;
                set
            }
        };
        sets.push((set, path));
    }
    Ok(Some(demo_buffer(
        &sets,
        s.task.task(),
        env_cfg.reward,
        s.features,
    )?))
}

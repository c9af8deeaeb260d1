//! The `[clone]` settings: the clone stage before the reinforcement learning.

use serde::{Deserialize, Serialize};

#[cfg(doc)]
use super::PresetArg;
use super::{TaskArg, TrainSettings};
use crate::learn::bc::BcConfig;
use crate::pipeline::clone_members::{
    self, CloneMember, DEFAULT_DISTIL_EPISODES_PER_ROUND, DEFAULT_DISTIL_ROUNDS, Ensemble,
    MembersError,
};
use crate::pipeline::imitation::ImitationConfig;

/// The clone stage of a pipeline run: `trainer imitate`'s recipe for the task
/// ([`ImitationConfig::for_task`]) with the run's seed, actor sizes, task features and evaluation
/// threads; each field, when set, overrides the recipe's.
///
/// Without members that is the stage: one imitation run per seed, in `OUT/clone/seed-S`. With
/// members (`[[clone.members]]`) it is an ensemble and its distillation
/// ([`crate::pipeline::clone_members`]): each member entry's runs (the recipe with the entry's
/// tweaks, at seeds derived from the pipeline seed) in `OUT/clone/seed-S/NAME-sK`, then one
/// network taught by the mean of their files over `distil_rounds` DAgger rounds in
/// `OUT/clone/seed-S/distil`, whose last round's file starts the fine-tune.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CloneStage {
    /// Clean demonstrator episodes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub demo_episodes: Option<u32>,
    /// Demonstrator episodes with noise on the executed actions (DART).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dart_episodes: Option<u32>,
    /// Stack only: DART episodes started with brick 1 in the hand.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub in_hand_episodes: Option<u32>,
    /// DART episodes from starts with the bricks close together
    /// ([`ImitationConfig::close_dart_episodes`]; unset: the recipe's, none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub close_dart_episodes: Option<u32>,
    /// Their largest spacing of the bricks' centres, metres ([`ImitationConfig::close_spacing`];
    /// unset: the recipe's 0.095).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub close_spacing: Option<f32>,
    /// Behaviour-cloning gradient steps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bc_steps: Option<u64>,
    /// Selection starts of the clone.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub select_episodes: Option<u32>,
    /// With members: DAgger rounds of the distillation (unset:
    /// [`clone_members::DEFAULT_DISTIL_ROUNDS`]); its last round's file starts the fine-tune.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distil_rounds: Option<u32>,
    /// With members: policy episodes labelled per distillation round (unset:
    /// [`clone_members::DEFAULT_DISTIL_EPISODES_PER_ROUND`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distil_episodes_per_round: Option<u32>,
    /// The ensemble (`[[clone.members]]`; empty: a single clone), in the order their files enter
    /// the distillation's mean.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub members: Vec<CloneMember>,
}

impl CloneStage {
    /// The imitation run of seed `seed` of a run with settings `s`.
    pub fn imitation(&self, s: &TrainSettings, seed: u64) -> ImitationConfig {
        let base = ImitationConfig::for_task(s.task.task());
        ImitationConfig {
            demo_episodes: self.demo_episodes.unwrap_or(base.demo_episodes),
            dart_episodes: self.dart_episodes.unwrap_or(base.dart_episodes),
            in_hand_episodes: self.in_hand_episodes.unwrap_or(base.in_hand_episodes),
            close_dart_episodes: self.close_dart_episodes.unwrap_or(base.close_dart_episodes),
            close_spacing: self.close_spacing.unwrap_or(base.close_spacing),
            select_episodes: self.select_episodes.unwrap_or(base.select_episodes),
            bc: BcConfig {
                steps: self.bc_steps.unwrap_or(base.bc.steps),
                hidden: s.run.ddpg.actor_hidden.clone(),
                features: s.features,
                ..base.bc.clone()
            },
            seed,
            eval_threads: s.eval_threads,
            ..base
        }
    }

    /// The ensemble and distillation of seed `seed` of a run with settings `s`, its members' files
    /// in `OUT/clone/seed-S` (None: no members, a single clone).
    pub fn ensemble(&self, s: &TrainSettings, seed: u64) -> Result<Option<Ensemble>, MembersError> {
        if self.members.is_empty() {
            clone_members::check_members(
                &self.members,
                self.distil_rounds,
                self.distil_episodes_per_round,
            )?;
            return Ok(None);
        }
        let dir = s.out.join("clone").join(format!("seed-{seed}"));
        Ensemble::new(
            &self.imitation(s, seed),
            &self.members,
            self.distil_rounds,
            self.distil_episodes_per_round,
            seed,
            &dir,
        )
        .map(Some)
    }

    /// The clone stage of the task's default pipeline ([`PresetArg::Finetune`]): the shipped
    /// recipe of its policy file. Grasp: members of the default recipe at seeds 0-3, with close
    /// bursts 0.02 at seeds 0-1 and with the teacher that tucks first at seeds 0-1, distilled
    /// over one round of 400 episodes at pipeline seed 1 (`experiments/grasp-distil.sh`,
    /// policies/grasp.dxpl). Stack (since session 38): one clone of Stack's recipe with
    /// [`STACK_CLOSE_DART_EPISODES`] more DART episodes from close starts, at pipeline seed 9
    /// (policies/stack.dxpl; the ensemble of seven clones that made the file before it is
    /// `experiments/stack-distil.toml`). The other tasks: one clone of the recipe
    /// (StackInHand's file is its clone fine-tuned).
    pub fn for_task(task: TaskArg) -> CloneStage {
        let member = |name: &str, seeds: &[u64]| CloneMember {
            name: name.to_owned(),
            seeds: seeds.to_vec(),
            ..CloneMember::default()
        };
        let members = match task {
            TaskArg::Grasp => vec![
                member("default", &[0, 1, 2, 3]),
                CloneMember {
                    close_bursts: Some(0.02),
                    ..member("close-bursts", &[0, 1])
                },
                CloneMember {
                    tuck_first: true,
                    ..member("tuck-first", &[0, 1])
                },
            ],
            TaskArg::Stack => {
                return CloneStage {
                    close_dart_episodes: Some(STACK_CLOSE_DART_EPISODES),
                    ..CloneStage::default()
                };
            }
            TaskArg::Reach | TaskArg::StackInHand => return CloneStage::default(),
        };
        CloneStage {
            members,
            distil_rounds: Some(DEFAULT_DISTIL_ROUNDS),
            distil_episodes_per_round: Some(DEFAULT_DISTIL_EPISODES_PER_ROUND),
            ..CloneStage::default()
        }
    }
}

/// Close-start DART episodes of Stack's default clone stage (at the recipe's 9.5 cm): with them
/// the clones of seeds 8 and 9 solved 3977 of 4000 development starts against their base twins'
/// 3928 (docs/experiments.md, session 37), where the Stack files' failures lie at spacings below
/// 10 cm.
pub const STACK_CLOSE_DART_EPISODES: u32 = 800;

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::env::Task;
    use crate::pipeline::train_settings::{PresetArg, SettingsError, load};

    /// The imitation seeds of the member runs of `task`'s default pipeline at pipeline seed `seed`,
    /// with their folders, in the order they enter the distillation's mean.
    fn member_seeds(task: TaskArg, seed: u64) -> Result<Vec<(String, u64)>, SettingsError> {
        let mut s = TrainSettings::for_task(task);
        s.seeds = vec![seed];
        s.validate()?;
        Ok(member_seeds_of(&s, seed))
    }

    /// The imitation seeds and folders of the member runs of settings `s` at pipeline seed `seed`.
    fn member_seeds_of(s: &TrainSettings, seed: u64) -> Vec<(String, u64)> {
        let e = s
            .clone
            .as_ref()
            .unwrap()
            .ensemble(s, seed)
            .unwrap()
            .unwrap();
        assert_eq!(e.distil.seed, seed);
        e.members
            .iter()
            .map(|m| (m.folder.clone(), m.config.seed))
            .collect()
    }

    #[test]
    fn the_default_clone_stages_are_the_shipped_recipes() {
        // Stack (policies/stack.dxpl since session 38): one clone of Stack's recipe with 800
        // close-start DART episodes at 9.5 cm, at pipeline seed 9: the command that made the file,
        // `trainer imitate --task stack --close-dart-episodes 800 --seeds 9`, field for field.
        let s = TrainSettings::for_task(TaskArg::Stack);
        assert_eq!(s.seeds, vec![9]);
        s.validate().unwrap();
        let stage = s.clone.as_ref().unwrap();
        assert!(stage.ensemble(&s, 9).unwrap().is_none(), "one clone");
        let want = ImitationConfig {
            close_dart_episodes: 800,
            seed: 9,
            bc: BcConfig {
                features: true,
                ..ImitationConfig::for_task(Task::Stack).bc
            },
            ..ImitationConfig::for_task(Task::Stack)
        };
        assert_eq!(
            serde_json::to_value(stage.imitation(&s, 9)).unwrap(),
            serde_json::to_value(&want).unwrap()
        );
        assert_eq!(
            (want.dart_episodes, want.in_hand_episodes, want.bc.steps),
            (800, 1600, 60_000)
        );
        assert_eq!(want.close_spacing, 0.095);
        // A run's own [clone] overrides the close-start episodes and their spacing.
        let own = CloneStage {
            close_dart_episodes: Some(0),
            close_spacing: Some(0.12),
            ..stage.clone()
        };
        let cfg = own.imitation(&s, 9);
        assert_eq!((cfg.close_dart_episodes, cfg.close_spacing), (0, 0.12));
        let bad = CloneStage {
            close_spacing: Some(0.5),
            ..stage.clone()
        };
        let mut refused = s.clone();
        refused.clone = Some(bad);
        assert!(matches!(refused.validate(), Err(SettingsError::Clone(_))));
        // experiments/grasp-distil.sh: the default recipe's seeds 0-3, close bursts 0.02 at 0-1,
        // the teacher that tucks first at 0-1, in this order; distilled at seed 1 (round 1).
        let grasp = member_seeds(TaskArg::Grasp, 1).unwrap();
        let want: Vec<(String, u64)> = [
            ("default-s0", 0),
            ("default-s1", 1),
            ("default-s2", 2),
            ("default-s3", 3),
            ("close-bursts-s0", 0),
            ("close-bursts-s1", 1),
            ("tuck-first-s0", 0),
            ("tuck-first-s1", 1),
        ]
        .iter()
        .map(|&(f, k)| (f.to_owned(), k))
        .collect();
        assert_eq!(grasp, want);
        let s = TrainSettings::for_task(TaskArg::Grasp);
        let e = s.clone.as_ref().unwrap().ensemble(&s, 1).unwrap().unwrap();
        assert_eq!((e.distil.rounds, e.distil.episodes_per_round), (1, 400));
        let tweaks: Vec<(f32, bool)> = e
            .members
            .iter()
            .map(|m| (m.config.close_bursts, m.config.tuck_first))
            .collect();
        assert_eq!(tweaks[3], (0.0, false));
        assert_eq!(tweaks[5], (0.02, false));
        assert_eq!(tweaks[6], (0.0, true));
        // Other pipeline seeds: members of their own, none shared with seed 1's.
        let two = member_seeds(TaskArg::Grasp, 2).unwrap();
        assert!(two.iter().all(|m| !grasp.contains(m)), "{two:?}");
        // Seed 0 would run negative member seeds.
        assert!(matches!(
            member_seeds(TaskArg::Grasp, 0),
            Err(SettingsError::CloneMembers(
                MembersError::NegativeSeed { .. }
            ))
        ));
    }

    #[test]
    fn the_ensemble_recipe_of_the_session23_stack_file_is_kept() {
        // experiments/stack-distil.toml with `--preset finetune`: session 25's default Stack
        // pipeline (policies/history/stack-session23.dxpl): Stack's recipe at seeds 1-7,
        // distilled at seed 1 over one round of 400 episodes, then the guarded fine-tune.
        let path = PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../experiments/stack-distil.toml"
        ));
        let mut s = load(Some(&path)).unwrap();
        PresetArg::Finetune.apply(&mut s);
        s.validate().unwrap();
        let mut then = TrainSettings::for_task(TaskArg::Stack);
        then.seeds = vec![1];
        then.out = PathBuf::from("runs/stack-distil");
        then.clone = s.clone.clone();
        assert_eq!(s, then, "the default pipeline but for its clone stage");
        let stack = member_seeds_of(&s, 1);
        let seeds: Vec<u64> = stack.iter().map(|m| m.1).collect();
        assert_eq!(seeds, (1..=7).collect::<Vec<_>>());
        let e = s.clone.as_ref().unwrap().ensemble(&s, 1).unwrap().unwrap();
        assert_eq!((e.distil.rounds, e.distil.episodes_per_round), (1, 400));
        let recipe = ImitationConfig::for_task(Task::Stack);
        for m in &e.members {
            let c = &m.config;
            assert_eq!(
                (
                    c.dart_episodes,
                    c.in_hand_episodes,
                    c.close_dart_episodes,
                    c.bc.steps,
                    &c.bc.hidden
                ),
                (recipe.dart_episodes, 1600, 0, 60_000, &vec![256, 256])
            );
            assert!(c.bc.features && !c.tuck_first && c.close_bursts == 0.0);
        }
        assert_eq!(
            e.distil.teacher_policies[0],
            PathBuf::from("runs/stack-distil/clone/seed-1/default-s1/policy.dxpl")
        );
        // Pipeline seed 2 runs members of its own.
        assert_eq!(member_seeds_of(&s, 2)[0].1, 8);
    }

    #[test]
    fn members_in_a_settings_file_and_their_refusals() {
        let dir = std::env::temp_dir().join(format!("dex-cfg-members-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("members.toml");
        let base = "task = \"grasp\"\nseeds = [1]\nfeatures = true\n[clone]\nbc_steps = 100\n\
                    distil_rounds = 2\n[[clone.members]]\nname = \"a\"\nseeds = [0, 1]\n\
                    [[clone.members]]\nname = \"b\"\nseeds = [0]\nclose_bursts = 0.02\n\
                    tuck_first = true\n";
        let load_with = |text: &str| {
            std::fs::write(&path, text).unwrap();
            load(Some(&path))
        };
        let s = load_with(base).unwrap();
        let stage = s.clone.as_ref().unwrap();
        assert_eq!(stage.members.len(), 2);
        assert_eq!(stage.members[1].close_bursts, Some(0.02));
        assert!(stage.members[1].tuck_first && !stage.members[0].tuck_first);
        s.validate().unwrap();
        let e = stage.ensemble(&s, 1).unwrap().unwrap();
        assert_eq!(e.members.len(), 3);
        assert_eq!(e.members[2].config.bc.steps, 100, "the stage's overrides");
        assert_eq!((e.distil.rounds, e.distil.episodes_per_round), (2, 400));
        // Written into the run folder and read back.
        let back: TrainSettings = toml::from_str(&s.to_toml().unwrap()).unwrap();
        assert_eq!(back, s);
        // A typo inside a member entry is an error.
        assert!(load_with(&base.replace("tuck_first", "tuck_frist")).is_err());
        let refused = |text: &str| load_with(text).unwrap().validate().unwrap_err();
        let members = |e: SettingsError| match e {
            SettingsError::CloneMembers(m) => m,
            other => panic!("{other}"),
        };
        assert!(matches!(
            members(refused(&base.replace("seeds = [0]", "seeds = []"))),
            MembersError::NoSeeds { .. }
        ));
        assert!(matches!(
            members(refused(
                &base.replace("distil_rounds = 2", "distil_rounds = 0")
            )),
            MembersError::NoDistilRounds
        ));
        assert!(matches!(
            members(refused(
                &base.replace("distil_rounds = 2", "distil_episodes_per_round = 0")
            )),
            MembersError::NoDistilEpisodes
        ));
        assert!(matches!(
            members(refused(&base.replace("seeds = [1]", "seeds = [1, 0]"))),
            MembersError::NegativeSeed {
                pipeline_seed: 0,
                ..
            }
        ));
        assert!(matches!(
            members(refused(&base.replace("name = \"b\"", "name = \"a\""))),
            MembersError::Duplicate { .. }
        ));
        // Distillation settings without members.
        let single = "task = \"grasp\"\nfeatures = true\n[clone]\ndistil_rounds = 1\n";
        assert!(matches!(
            members(refused(single)),
            MembersError::DistilWithoutMembers
        ));
        // Members and an init_policy: two starting points.
        let init = base.replace(
            "features = true\n",
            "features = true\ninit_policy = \"p.dxpl\"\n",
        );
        assert!(matches!(refused(&init), SettingsError::CloneAndInitPolicy));
        let _ = std::fs::remove_dir_all(&dir);
    }
}

//! The clone stage as an ensemble and its distillation (`[[clone.members]]`, `distil_rounds`,
//! `distil_episodes_per_round` of `[clone]`): several imitation runs (the members), then one
//! network distilled from the mean of their actions (`trainer imitate --teacher-policies`), whose
//! last round's file starts the fine-tune. This file holds the settings, the rule that gives each
//! member its seed from the pipeline seed, and the imitation runs they make
//! ([`Ensemble`]); `train_run::members` runs them.
//!
//! **Member seeds.** A member entry lists the seeds of its runs at pipeline seed 1 (the documented
//! seed of the shipped recipes: `trainer train --task grasp|stack --seeds 1`). At pipeline seed
//! `S` a listed seed `k` runs as
//!
//! ```text
//! k + w * (S - 1),   w = max - min + 1 over every listed seed of the stage (its seed span)
//! ```
//!
//! so seed 1 runs the listed seeds as written, and two pipeline seeds never share a member run
//! (Stack's seeds 1..7 run as 8..14 at `S = 2`, 15..21 at `S = 3`): the pipeline seeds of a run
//! are independent replicates of the recipe, as they are without members. The simpler
//! `k + (S - 1)` would give seed 2 six of seed 1's seven Stack members, and their spread would
//! understate the recipe's. A pipeline seed that would make a member seed negative (`S = 0`
//! when a listed seed is below the span, as Grasp's 0 is) is refused before any work, and so is
//! one that makes it [`MAX_MEMBER_SEED`] or more. The distillation runs at the pipeline seed
//! itself, as the shipped recipes' did at seed 1.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::pipeline::imitation::{ImitationConfig, ImitationError};

/// DAgger rounds of the distillation when `[clone]` has members and no `distil_rounds`: the
/// shipped Stack recipe's (`experiments/stack-distil.sh`), and the round the shipped Grasp file
/// came from (its run had two rounds; round 1's file does not depend on a later round).
pub const DEFAULT_DISTIL_ROUNDS: u32 = 1;

/// Policy episodes labelled per distillation round when `[clone]` has members and no
/// `distil_episodes_per_round` (both shipped recipes').
pub const DEFAULT_DISTIL_EPISODES_PER_ROUND: u32 = 400;

/// Member seeds stay below this: the imitation learner records from start seeds
/// `DEMO_SEED + 1000 * seed + ...` ([`crate::env::seeds::DEMO_SEED`]), which from seed 500 on
/// reach the demonstration buffers of `trainer train` (`DEMO_SEED + 500,000 + seed`) and from
/// 1000 on the confirmation starts.
pub const MAX_MEMBER_SEED: u64 = 500;

/// The folder of a pipeline seed's distillation, beside its members' (`OUT/clone/seed-S/distil`).
pub const DISTIL_FOLDER: &str = "distil";

/// One entry of the clone stage's ensemble (`[[clone.members]]`): the stage's imitation run
/// (the task's recipe with `[clone]`'s overrides) with this entry's tweaks, at each of its seeds.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CloneMember {
    /// The entry's name: its runs are the folders `NAME-sK` (`K` the member seed) of
    /// `OUT/clone/seed-S`. ASCII letters, digits, `-` and `_`.
    pub name: String,
    /// Seeds of the entry's runs at pipeline seed 1, one run each; other pipeline seeds shift them
    /// (the module's member-seed rule).
    pub seeds: Vec<u64>,
    /// Close bursts in the DART episodes ([`ImitationConfig::close_bursts`]; unset: the
    /// recipe's).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub close_bursts: Option<f32>,
    /// The Markov teacher tucks first ([`ImitationConfig::tuck_first`]).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub tuck_first: bool,
}

/// Why the clone stage's members or distillation settings are refused.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MembersError {
    /// A member entry without a usable name.
    #[error(
        "clone.members entry {index} has name {name:?}: a member needs a name of ASCII letters, \
         digits, '-' and '_' (its runs are the folders NAME-sK)"
    )]
    BadName {
        /// The entry's place in the list (from 0).
        index: usize,
        /// The name given.
        name: String,
    },
    /// A member entry without seeds.
    #[error("clone.members entry {name:?} lists no seeds: give it at least one")]
    NoSeeds {
        /// The entry's name.
        name: String,
    },
    /// Two member runs would share a folder (a name or a seed given twice).
    #[error("two clone member runs are both {folder:?}: names and each entry's seeds must differ")]
    Duplicate {
        /// The folder both would use.
        folder: String,
    },
    /// `distil_rounds` or `distil_episodes_per_round` without members.
    #[error(
        "clone.distil_rounds and clone.distil_episodes_per_round distil the members \
         ([[clone.members]]): the stage has none"
    )]
    DistilWithoutMembers,
    /// A distillation without DAgger rounds.
    #[error(
        "clone.distil_rounds is 0: the distillation needs at least one DAgger round (round 0 has \
         only the members' own states; its rounds label the distilled network's)"
    )]
    NoDistilRounds,
    /// A distillation round without episodes.
    #[error("clone.distil_episodes_per_round is 0: each distillation round needs episodes")]
    NoDistilEpisodes,
    /// A pipeline seed that gives a member a negative seed.
    #[error(
        "pipeline seed {pipeline_seed} gives clone member {name:?}'s seed {listed} the seed \
         {listed} + {stride} * ({pipeline_seed} - 1) < 0 (member seed = listed + span of the \
         listed seeds * (S - 1)): use seeds from 1"
    )]
    NegativeSeed {
        /// The member entry.
        name: String,
        /// The seed it lists.
        listed: u64,
        /// The stage's seed span.
        stride: u64,
        /// The pipeline seed.
        pipeline_seed: u64,
    },
    /// A pipeline seed that gives a member a seed of [`MAX_MEMBER_SEED`] or more.
    #[error(
        "pipeline seed {pipeline_seed} gives clone member {name:?} the seed {listed} + {stride} * \
         ({pipeline_seed} - 1), not below {MAX_MEMBER_SEED} (its demonstrations would start where \
         other seed ranges do)"
    )]
    SeedTooLarge {
        /// The member entry.
        name: String,
        /// The seed it lists.
        listed: u64,
        /// The stage's seed span.
        stride: u64,
        /// The pipeline seed.
        pipeline_seed: u64,
    },
    /// A member's or the distillation's imitation settings are out of range.
    #[error("clone member run {folder}")]
    Imitation {
        /// The run's folder name (`NAME-sK` or `distil`).
        folder: String,
        /// Why.
        #[source]
        source: ImitationError,
    },
}

/// One member run of a pipeline seed.
#[derive(Debug, Clone, PartialEq)]
pub struct MemberRun {
    /// Its folder under `OUT/clone/seed-S` (`NAME-sK`).
    pub folder: String,
    /// Its imitation run (one evaluation thread: members run side by side).
    pub config: ImitationConfig,
}

/// The clone stage of one pipeline seed with members: the member runs, in the order their files
/// enter the teacher's mean, and the distillation.
#[derive(Debug, Clone, PartialEq)]
pub struct Ensemble {
    /// The members, entry by entry, each entry's seeds in the order listed.
    pub members: Vec<MemberRun>,
    /// The distillation: the stage's imitation run at the pipeline seed with the members' files
    /// (`NAME-sK/policy.dxpl` under the stage's folder) as the teacher.
    pub distil: ImitationConfig,
}

/// The seed span of `members`: max - min + 1 over every listed seed (1 when none are listed).
pub fn seed_stride(members: &[CloneMember]) -> u64 {
    let seeds = members.iter().flat_map(|m| m.seeds.iter().copied());
    match (seeds.clone().min(), seeds.max()) {
        (Some(lo), Some(hi)) => hi - lo + 1,
        _ => 1,
    }
}

/// The seed of the run of `member`'s listed seed `listed` at pipeline seed `pipeline_seed`, for a
/// stage of seed span `stride` ([`seed_stride`]): `listed + stride * (pipeline_seed - 1)`.
pub fn member_seed(
    member: &CloneMember,
    listed: u64,
    stride: u64,
    pipeline_seed: u64,
) -> Result<u64, MembersError> {
    let base = u128::from(listed) + u128::from(stride) * u128::from(pipeline_seed);
    let Some(seed) = base.checked_sub(u128::from(stride)) else {
        return Err(MembersError::NegativeSeed {
            name: member.name.clone(),
            listed,
            stride,
            pipeline_seed,
        });
    };
    if seed >= u128::from(MAX_MEMBER_SEED) {
        return Err(MembersError::SeedTooLarge {
            name: member.name.clone(),
            listed,
            stride,
            pipeline_seed,
        });
    }
    Ok(seed as u64)
}

/// Checks the members and the distillation's settings that do not depend on the pipeline seed.
pub fn check_members(
    members: &[CloneMember],
    distil_rounds: Option<u32>,
    distil_episodes_per_round: Option<u32>,
) -> Result<(), MembersError> {
    if members.is_empty() {
        if distil_rounds.is_some() || distil_episodes_per_round.is_some() {
            return Err(MembersError::DistilWithoutMembers);
        }
        return Ok(());
    }
    for (index, m) in members.iter().enumerate() {
        let usable = |c: char| c.is_ascii_alphanumeric() || c == '-' || c == '_';
        if m.name.is_empty() || !m.name.chars().all(usable) {
            return Err(MembersError::BadName {
                index,
                name: m.name.clone(),
            });
        }
        if m.seeds.is_empty() {
            return Err(MembersError::NoSeeds {
                name: m.name.clone(),
            });
        }
    }
    if distil_rounds == Some(0) {
        return Err(MembersError::NoDistilRounds);
    }
    if distil_episodes_per_round == Some(0) {
        return Err(MembersError::NoDistilEpisodes);
    }
    Ok(())
}

impl Ensemble {
    /// The runs of pipeline seed `pipeline_seed` whose clone stage is `base` (the stage's
    /// imitation run, any seed) with `members`, distilled over `distil_rounds` rounds of
    /// `distil_episodes_per_round` episodes (unset: [`DEFAULT_DISTIL_ROUNDS`],
    /// [`DEFAULT_DISTIL_EPISODES_PER_ROUND`]); the members' files are read from `stage_dir`
    /// (`OUT/clone/seed-S`). Every run's settings are validated; `members` must not be empty.
    pub fn new(
        base: &ImitationConfig,
        members: &[CloneMember],
        distil_rounds: Option<u32>,
        distil_episodes_per_round: Option<u32>,
        pipeline_seed: u64,
        stage_dir: &Path,
    ) -> Result<Ensemble, MembersError> {
        check_members(members, distil_rounds, distil_episodes_per_round)?;
        let stride = seed_stride(members);
        let mut runs: Vec<MemberRun> = Vec::new();
        for m in members {
            for &listed in &m.seeds {
                let seed = member_seed(m, listed, stride, pipeline_seed)?;
                let folder = format!("{}-s{seed}", m.name);
                if runs.iter().any(|r| r.folder == folder) {
                    return Err(MembersError::Duplicate { folder });
                }
                let config = ImitationConfig {
                    seed,
                    close_bursts: m.close_bursts.unwrap_or(base.close_bursts),
                    tuck_first: m.tuck_first || base.tuck_first,
                    eval_threads: 1,
                    ..base.clone()
                };
                config
                    .validate()
                    .map_err(|source| MembersError::Imitation {
                        folder: folder.clone(),
                        source,
                    })?;
                runs.push(MemberRun { folder, config });
            }
        }
        let distil = ImitationConfig {
            seed: pipeline_seed,
            teacher_policies: runs
                .iter()
                .map(|r| member_policy(stage_dir, &r.folder))
                .collect(),
            rounds: distil_rounds.unwrap_or(DEFAULT_DISTIL_ROUNDS),
            episodes_per_round: distil_episodes_per_round
                .unwrap_or(DEFAULT_DISTIL_EPISODES_PER_ROUND),
            ..base.clone()
        };
        distil
            .validate()
            .map_err(|source| MembersError::Imitation {
                folder: DISTIL_FOLDER.to_owned(),
                source,
            })?;
        Ok(Ensemble {
            members: runs,
            distil,
        })
    }

    /// The distilled policy file under `stage_dir`: the distillation's last round
    /// (`distil/policy-R.dxpl`), which starts the fine-tune.
    pub fn distilled_policy(&self, stage_dir: &Path) -> PathBuf {
        stage_dir
            .join(DISTIL_FOLDER)
            .join(format!("policy-{}.dxpl", self.distil.rounds))
    }
}

/// A member run's policy file under the stage's folder (the run's best round, `policy.dxpl`).
pub fn member_policy(stage_dir: &Path, folder: &str) -> PathBuf {
    stage_dir.join(folder).join("policy.dxpl")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::Task;

    fn member(name: &str, seeds: &[u64]) -> CloneMember {
        CloneMember {
            name: name.into(),
            seeds: seeds.to_vec(),
            ..CloneMember::default()
        }
    }

    fn seeds(e: &Ensemble) -> Vec<(String, u64)> {
        e.members
            .iter()
            .map(|r| (r.folder.clone(), r.config.seed))
            .collect()
    }

    #[test]
    fn seed_one_runs_the_listed_seeds_and_other_seeds_shift_by_the_span() {
        let base = ImitationConfig::for_task(Task::Stack);
        let stack = [member("default", &[1, 2, 3, 4, 5, 6, 7])];
        let dir = Path::new("out/clone/seed-1");
        let e = Ensemble::new(&base, &stack, None, None, 1, dir).unwrap();
        let got: Vec<u64> = e.members.iter().map(|r| r.config.seed).collect();
        assert_eq!(got, (1..=7).collect::<Vec<_>>());
        assert_eq!(e.members[0].folder, "default-s1");
        assert_eq!((e.distil.seed, e.distil.rounds), (1, 1));
        assert_eq!(e.distil.episodes_per_round, 400);
        assert_eq!(
            e.distil.teacher_policies[6],
            dir.join("default-s7/policy.dxpl")
        );
        assert_eq!(e.distilled_policy(dir), dir.join("distil/policy-1.dxpl"));
        let two = Ensemble::new(&base, &stack, None, None, 2, dir).unwrap();
        let got: Vec<u64> = two.members.iter().map(|r| r.config.seed).collect();
        assert_eq!(got, (8..=14).collect::<Vec<_>>());
        assert_eq!(two.distil.seed, 2);
        // Seed 0 would run seeds -6..0.
        let e = Ensemble::new(&base, &stack, None, None, 0, dir).unwrap_err();
        assert!(
            matches!(
                e,
                MembersError::NegativeSeed {
                    listed: 1,
                    stride: 7,
                    ..
                }
            ),
            "{e}"
        );
        // Far seeds are refused before their demonstrations reach other seed ranges.
        let e = Ensemble::new(&base, &stack, None, None, 72, dir).unwrap_err();
        assert!(matches!(e, MembersError::SeedTooLarge { .. }), "{e}");
        assert!(Ensemble::new(&base, &stack, None, None, 71, dir).is_ok());
    }

    #[test]
    fn members_keep_their_tweaks_and_take_one_evaluation_thread() {
        let base = ImitationConfig {
            eval_threads: 2,
            ..ImitationConfig::for_task(Task::Grasp)
        };
        let grasp = [
            member("default", &[0, 1, 2, 3]),
            CloneMember {
                close_bursts: Some(0.02),
                ..member("close-bursts", &[0, 1])
            },
            CloneMember {
                tuck_first: true,
                ..member("tuck-first", &[0, 1])
            },
        ];
        let dir = Path::new("o");
        let e = Ensemble::new(&base, &grasp, Some(2), Some(10), 1, dir).unwrap();
        let tuned: Vec<(f32, bool, usize)> = e
            .members
            .iter()
            .map(|r| {
                (
                    r.config.close_bursts,
                    r.config.tuck_first,
                    r.config.eval_threads,
                )
            })
            .collect();
        assert_eq!(tuned[0], (0.0, false, 1));
        assert_eq!(tuned[4], (0.02, false, 1));
        assert_eq!(tuned[7], (0.0, true, 1));
        assert_eq!(e.members[7].config.dart_episodes, base.dart_episodes);
        assert_eq!(
            (
                e.distil.rounds,
                e.distil.episodes_per_round,
                e.distil.eval_threads
            ),
            (2, 10, 2)
        );
        assert!(!e.distil.tuck_first && e.distil.close_bursts == 0.0);
        assert_eq!(e.distilled_policy(dir), dir.join("distil/policy-2.dxpl"));
        // At seed 2 the span (4) shifts every entry alike.
        let e = Ensemble::new(&base, &grasp, None, None, 2, dir).unwrap();
        assert_eq!(
            seeds(&e)[3..6],
            [
                ("default-s7".to_owned(), 7),
                ("close-bursts-s4".to_owned(), 4),
                ("close-bursts-s5".to_owned(), 5)
            ]
        );
    }

    #[test]
    fn bad_members_and_distillations_are_refused() {
        let base = ImitationConfig::default();
        let dir = Path::new("o");
        let ok = member("a", &[0]);
        let new = |m: &[CloneMember], r, e| Ensemble::new(&base, m, r, e, 1, dir);
        assert!(matches!(
            new(&[member("a", &[])], None, None),
            Err(MembersError::NoSeeds { .. })
        ));
        for name in ["", "a/b", "..", "a b"] {
            assert!(matches!(
                new(&[member(name, &[0])], None, None),
                Err(MembersError::BadName { index: 0, .. })
            ));
        }
        assert!(matches!(
            new(&[ok.clone(), member("a", &[0])], None, None),
            Err(MembersError::Duplicate { .. })
        ));
        assert!(matches!(
            new(&[member("a", &[3, 3])], None, None),
            Err(MembersError::Duplicate { .. })
        ));
        assert!(matches!(
            new(std::slice::from_ref(&ok), Some(0), None),
            Err(MembersError::NoDistilRounds)
        ));
        assert!(matches!(
            new(std::slice::from_ref(&ok), None, Some(0)),
            Err(MembersError::NoDistilEpisodes)
        ));
        let bursts = CloneMember {
            close_bursts: Some(0.9),
            ..ok.clone()
        };
        let e = new(&[bursts], None, None).unwrap_err();
        assert!(
            matches!(&e, MembersError::Imitation { folder, .. } if folder == "a-s0"),
            "{e}"
        );
        assert!(matches!(
            check_members(&[], Some(1), None),
            Err(MembersError::DistilWithoutMembers)
        ));
        assert!(check_members(&[], None, None).is_ok());
    }
}

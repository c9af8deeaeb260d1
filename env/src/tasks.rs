//! The tasks: what the start state looks like, how long an episode is, which reward it uses by default and
//! when it counts as solved.

use super::rewards::{Predicates, Reward};

/// Control steps of a full episode (150 x 50 ms = 7.5 s, as in the paper).
pub const EPISODE_STEPS: u32 = 150;
/// Control steps of a Reach episode.
pub const REACH_EPISODE_STEPS: u32 = 50;

/// A task of the paper (plus a short Reach task for fast learner tests).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Task {
    /// Both bricks on the table; lift brick 1. Success: grasp predicate (brick 1 above 3 cm) at the end.
    Grasp,
    /// Brick 1 starts held between the closed fingers; stack it. Success: stack predicate at the end.
    StackInHand,
    /// Both bricks on the table; stack brick 1 on brick 2. Success: stack predicate at the end.
    Stack,
    /// Both bricks on the table; bring the pinch site into brick 1's reach box. Success: reach predicate at
    /// the end. Episodes are [`REACH_EPISODE_STEPS`] long.
    Reach,
}

impl From<dex_policy::Task> for Task {
    /// The task a policy file names (its header's task field).
    fn from(t: dex_policy::Task) -> Self {
        match t {
            dex_policy::Task::Grasp => Task::Grasp,
            dex_policy::Task::StackInHand => Task::StackInHand,
            dex_policy::Task::Stack => Task::Stack,
            dex_policy::Task::Reach => Task::Reach,
        }
    }
}

impl Task {
    /// All tasks.
    pub const ALL: [Task; 4] = [Task::Grasp, Task::StackInHand, Task::Stack, Task::Reach];

    /// Control steps per episode.
    pub const fn episode_steps(self) -> u32 {
        match self {
            Task::Reach => REACH_EPISODE_STEPS,
            _ => EPISODE_STEPS,
        }
    }

    /// Whether demonstrations of `other` are valid training data for a policy of this task: its
    /// own, and for Stack those of StackInHand (the same success and observation, started where
    /// Stack's grasp ends: the paper's in-hand instructive starts, as data).
    pub const fn learns_from(self, other: Task) -> bool {
        matches!(
            (self, other),
            (Task::Stack, Task::Stack | Task::StackInHand)
                | (Task::StackInHand, Task::StackInHand)
                | (Task::Grasp, Task::Grasp)
                | (Task::Reach, Task::Reach)
        )
    }

    /// The task's own sparse reward (used unless the configuration names another).
    pub const fn default_reward(self) -> Reward {
        match self {
            Task::Grasp => Reward::SparseGrasp,
            Task::StackInHand | Task::Stack => Reward::SparseStack,
            Task::Reach => Reward::SparseReach,
        }
    }

    /// Whether a state with predicates `p` counts as solved; evaluation reads it at the episode's last step.
    pub const fn is_success(self, p: Predicates) -> bool {
        match self {
            Task::Grasp => p.grasp,
            Task::StackInHand | Task::Stack => p.stack,
            Task::Reach => p.reach,
        }
    }

    /// Lower and upper bound of the pinch site's start height, metres (dm_control: 0.15-0.4 for stacking,
    /// 0.2-0.4 for lifting).
    pub const fn start_height(self) -> (f64, f64) {
        match self {
            Task::Grasp | Task::Reach => (0.2, 0.4),
            Task::Stack | Task::StackInHand => (0.15, 0.4),
        }
    }
}

impl std::str::FromStr for Task {
    type Err = UnknownTask;

    /// Parses `grasp`, `stack-in-hand`, `stack` or `reach` (for command lines; the library uses the enum).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "grasp" => Ok(Task::Grasp),
            "stack-in-hand" | "stack_in_hand" => Ok(Task::StackInHand),
            "stack" => Ok(Task::Stack),
            "reach" => Ok(Task::Reach),
            _ => Err(UnknownTask(s.to_owned())),
        }
    }
}

/// A task name that [`Task::from_str`](std::str::FromStr) does not know.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown task `{0}` (expected grasp, stack-in-hand, stack or reach)")]
pub struct UnknownTask(pub String);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn success_definitions() {
        let none = Predicates::default();
        let grasp = Predicates {
            reach: true,
            grasp: true,
            stack: false,
        };
        let stack = Predicates {
            reach: true,
            grasp: false,
            stack: true,
        };
        assert!(!Task::Grasp.is_success(none) && Task::Grasp.is_success(grasp));
        assert!(Task::Stack.is_success(stack) && !Task::Stack.is_success(grasp));
        assert!(Task::StackInHand.is_success(stack));
        assert!(Task::Stack.learns_from(Task::StackInHand));
        assert!(!Task::StackInHand.learns_from(Task::Stack));
        assert!(!Task::Stack.learns_from(Task::Grasp));
        assert!(Task::ALL.iter().all(|&t| t.learns_from(t)));
        assert!(Task::Reach.is_success(grasp));
        for t in Task::ALL {
            let name = format!("{t:?}");
            assert!(!name.is_empty());
        }
        for (file, t) in [
            (dex_policy::Task::Grasp, Task::Grasp),
            (dex_policy::Task::StackInHand, Task::StackInHand),
            (dex_policy::Task::Stack, Task::Stack),
            (dex_policy::Task::Reach, Task::Reach),
        ] {
            assert_eq!(Task::from(file), t, "a file's {file:?}");
        }
        assert_eq!("stack-in-hand".parse::<Task>(), Ok(Task::StackInHand));
        assert!("lift".parse::<Task>().is_err());
    }
}

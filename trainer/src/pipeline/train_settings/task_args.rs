//! The task, reward and start-scheme names of the command line and of settings files.

use serde::{Deserialize, Serialize};

use crate::env::{EnvConfig, Reward, Task};

/// Task names on the command line and in config files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TaskArg {
    /// Bring the pinch site to brick 1 (50 steps; learns in minutes).
    Reach,
    /// Lift brick 1.
    Grasp,
    /// Stack brick 1, starting in the hand.
    StackInHand,
    /// Pick up brick 1 and stack it.
    Stack,
}

impl TaskArg {
    /// The environment's task.
    pub fn task(self) -> Task {
        match self {
            TaskArg::Reach => Task::Reach,
            TaskArg::Grasp => Task::Grasp,
            TaskArg::StackInHand => Task::StackInHand,
            TaskArg::Stack => Task::Stack,
        }
    }

    /// From the environment's task.
    pub fn from_task(task: Task) -> Self {
        match task {
            Task::Reach => TaskArg::Reach,
            Task::Grasp => TaskArg::Grasp,
            Task::StackInHand => TaskArg::StackInHand,
            Task::Stack => TaskArg::Stack,
        }
    }

    /// From a policy file's task.
    pub fn from_policy(task: dex_policy::Task) -> Self {
        match task {
            dex_policy::Task::Reach => TaskArg::Reach,
            dex_policy::Task::Grasp => TaskArg::Grasp,
            dex_policy::Task::StackInHand => TaskArg::StackInHand,
            dex_policy::Task::Stack => TaskArg::Stack,
        }
    }
}

/// Reward names on the command line and in config files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RewardArg {
    /// The task's own sparse reward.
    TaskDefault,
    /// Paper: 1 if stacked.
    SparseStack,
    /// Paper: 1 stacked, 0.25 grasped.
    GraspShaping,
    /// Paper: 1 stacked, 0.25 grasped, 0.125 reached.
    ReachGraspShaping,
    /// Paper: full composite with the tanh^2 distance terms.
    FullComposite,
    /// 1 if brick 1 is lifted.
    SparseGrasp,
    /// 1 if the pinch site is in the reach box.
    SparseReach,
    /// 1 in the reach box, else a broad distance term (the Reach task's dense reward).
    ReachShaping,
}

impl RewardArg {
    /// The environment configuration for `task` with this reward.
    pub fn env_config(self, task: Task) -> EnvConfig {
        let base = EnvConfig::new(task);
        let reward = match self {
            RewardArg::TaskDefault => return base,
            RewardArg::SparseStack => Reward::SparseStack,
            RewardArg::GraspShaping => Reward::GraspShaping,
            RewardArg::ReachGraspShaping => Reward::ReachGraspShaping,
            RewardArg::FullComposite => Reward::FullComposite,
            RewardArg::SparseGrasp => Reward::SparseGrasp,
            RewardArg::SparseReach => Reward::SparseReach,
            RewardArg::ReachShaping => Reward::ReachShaping,
        };
        base.with_reward(reward)
    }
}

/// Start-state scheme names on the command line and in config files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StartArg {
    /// The task's own start states.
    Original,
    /// The in-hand start with probability `start.in_hand_probability`, else the original one.
    Mixture,
    /// States along the scripted demonstrator's trajectories; short training episodes.
    AlongDemonstrations,
}

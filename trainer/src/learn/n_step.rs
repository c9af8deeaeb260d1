//! n-step returns: a worker's last `n` steps folded into one replay transition
//! `(s_t, a_t, sum_{i<m} gamma^i r_{t+i}, s_{t+m})` with bootstrap factor `gamma^m` (m = n, or fewer
//! at an episode's end).
//!
//! Time limits are handled as in the one-step case: an episode cut by its step limit (or the
//! environment's own limit) still bootstraps from the last observation, through `gamma^m` with the
//! `m` steps actually left; only a terminal step stops the bootstrap. The replay stores the factor
//! divided by `gamma` (its `not_done` column, 1 or 0 for `n` = 1, so the critic's target stays
//! `y = r + gamma * not_done * Q'`) and one-step replay rows are exactly what they were.
//!
//! Off-policy bias: the `n - 1` inner actions are the behaviour policy's; with small `n` (3-5) and
//! a replay of recent data this is the usual trade (Barth-Maron et al. 2018, D4PG; Hessel et al.
//! 2018, Rainbow).

/// One step kept until its n-step transition is complete.
#[derive(Debug, Clone)]
struct Pending {
    obs: Vec<f32>,
    act: Vec<f32>,
    reward: f32,
}

/// The queue of a worker's most recent steps (fixed capacity `n`, allocated once).
#[derive(Debug, Clone)]
pub struct NStepQueue {
    n: usize,
    gamma: f32,
    slots: Vec<Pending>,
    /// Index of the oldest pending step in `slots`.
    head: usize,
    len: usize,
}

/// A finished n-step transition, borrowed from the queue.
#[derive(Debug, Clone, Copy)]
pub struct NStepTransition<'a> {
    /// Observation of the first step.
    pub obs: &'a [f32],
    /// Action of the first step.
    pub act: &'a [f32],
    /// Discounted sum of the rewards of the steps folded in.
    pub reward: f32,
    /// Bootstrap factor divided by gamma: `gamma^(m-1)`, 0 after a terminal step.
    pub not_done: f32,
}

impl NStepQueue {
    /// A queue for `n`-step returns (`n` 0 is taken as 1) with discount `gamma`.
    pub fn new(n: usize, gamma: f32, obs_dim: usize, act_dim: usize) -> Self {
        let n = n.max(1);
        NStepQueue {
            n,
            gamma,
            slots: (0..n)
                .map(|_| Pending {
                    obs: vec![0.0; obs_dim],
                    act: vec![0.0; act_dim],
                    reward: 0.0,
                })
                .collect(),
            head: 0,
            len: 0,
        }
    }

    /// Adds one environment step; `emit` receives every transition this completes, each with the
    /// observation after the step as its next observation: one when the queue is full, all pending
    /// ones when the episode ends here (`terminal`, or `episode_end` for a time limit).
    pub fn push(
        &mut self,
        obs: &[f32],
        act: &[f32],
        reward: f32,
        terminal: bool,
        episode_end: bool,
        mut emit: impl FnMut(NStepTransition<'_>),
    ) {
        let tail = (self.head + self.len) % self.n;
        let slot = &mut self.slots[tail];
        let k = slot.obs.len().min(obs.len());
        slot.obs[..k].copy_from_slice(&obs[..k]);
        let k = slot.act.len().min(act.len());
        slot.act[..k].copy_from_slice(&act[..k]);
        slot.reward = reward;
        self.len += 1;
        let flush = terminal || episode_end;
        while self.len == self.n || (flush && self.len > 0) {
            let m = self.len;
            let mut ret = 0.0f32;
            let mut g = 1.0f32;
            for i in 0..m {
                ret += g * self.slots[(self.head + i) % self.n].reward;
                g *= self.gamma;
            }
            let not_done = if terminal {
                0.0
            } else {
                self.gamma.powi(m as i32 - 1)
            };
            let first = &self.slots[self.head];
            emit(NStepTransition {
                obs: &first.obs,
                act: &first.act,
                reward: ret,
                not_done,
            });
            self.head = (self.head + 1) % self.n;
            self.len -= 1;
        }
        if flush {
            self.head = 0;
            self.len = 0;
        }
    }

    /// Drops pending steps (an episode abandoned mid-way).
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// (first obs, reward, not_done) of every emitted transition over an episode of `rewards`.
    fn run(n: usize, rewards: &[f32], terminal_last: bool) -> Vec<(f32, f32, f32)> {
        let mut q = NStepQueue::new(n, 0.5, 1, 1);
        let mut out = Vec::new();
        for (t, &r) in rewards.iter().enumerate() {
            let last = t + 1 == rewards.len();
            q.push(&[t as f32], &[0.0], r, last && terminal_last, last, |tr| {
                out.push((tr.obs[0], tr.reward, tr.not_done))
            });
        }
        out
    }

    #[test]
    fn one_step_is_the_plain_transition() {
        assert_eq!(
            run(1, &[1.0, 2.0, 3.0], false),
            vec![(0.0, 1.0, 1.0), (1.0, 2.0, 1.0), (2.0, 3.0, 1.0)]
        );
        assert_eq!(run(1, &[1.0, 2.0], true).last(), Some(&(1.0, 2.0, 0.0)));
    }

    #[test]
    fn three_step_sums_and_discounts_and_flushes_at_a_time_limit() {
        // gamma 0.5: r0 + 0.5 r1 + 0.25 r2, bootstrap gamma^3 stored as gamma^2 = 0.25.
        let got = run(3, &[1.0, 2.0, 4.0, 8.0], false);
        assert_eq!(
            got,
            vec![
                (0.0, 1.0 + 1.0 + 1.0, 0.25),
                (1.0, 2.0 + 2.0 + 2.0, 0.25),
                // Time limit after step 3: the tail bootstraps with the steps it has.
                (2.0, 4.0 + 4.0, 0.5),
                (3.0, 8.0, 1.0),
            ]
        );
    }

    #[test]
    fn a_terminal_step_stops_every_pending_bootstrap() {
        let got = run(3, &[0.0, 0.0, 1.0], true);
        assert_eq!(
            got,
            vec![(0.0, 0.25, 0.0), (1.0, 0.5, 0.0), (2.0, 1.0, 0.0)]
        );
    }
}

//! Uniform experience replay of bounded capacity (a ring: the oldest transition is overwritten).
//!
//! Storage is one flat `f32` array per field, allocated once at construction; sampling gathers a
//! mini-batch into a caller-owned [`Batch`] without allocating.

use super::rng::Rng;

/// One mini-batch, row-major, reused across updates.
#[derive(Debug, Clone)]
pub struct Batch {
    /// Number of rows filled.
    pub len: usize,
    /// Observations, `len x obs_dim`.
    pub obs: Vec<f32>,
    /// Actions, `len x act_dim`.
    pub act: Vec<f32>,
    /// Rewards.
    pub reward: Vec<f32>,
    /// Next observations, `len x obs_dim`.
    pub next_obs: Vec<f32>,
    /// Discount multiplier of the bootstrap term: 0 after a terminal step, else 1 (for n-step
    /// rows `gamma^(n-1)`, see [`super::n_step`]).
    pub not_done: Vec<f32>,
    /// The first `demo_rows` rows have a cloning target: the demonstration buffer's rows, then,
    /// when the replay stores teacher labels ([`Replay::with_labels`]), every replay row too.
    pub demo_rows: usize,
    /// Cloning targets of those rows, `demo_rows x act_dim`.
    pub bc_target: Vec<f32>,
}

impl Batch {
    /// Buffers for up to `size` rows.
    pub fn new(size: usize, obs_dim: usize, act_dim: usize) -> Self {
        Batch {
            len: 0,
            obs: vec![0.0; size * obs_dim],
            act: vec![0.0; size * act_dim],
            reward: vec![0.0; size],
            next_obs: vec![0.0; size * obs_dim],
            not_done: vec![0.0; size],
            demo_rows: 0,
            bc_target: vec![0.0; size * act_dim],
        }
    }

    /// Capacity in rows.
    pub fn capacity(&self) -> usize {
        self.reward.len()
    }
}

/// Ring buffer of transitions.
#[derive(Debug, Clone)]
pub struct Replay {
    obs_dim: usize,
    act_dim: usize,
    capacity: usize,
    len: usize,
    next: usize,
    obs: Vec<f32>,
    act: Vec<f32>,
    reward: Vec<f32>,
    next_obs: Vec<f32>,
    not_done: Vec<f32>,
    /// The teacher's action at each stored observation (`capacity x act_dim`), when the run
    /// labels its transitions ([`Replay::with_labels`]): the cloning target of every row.
    labels: Option<Vec<f32>>,
}

impl Replay {
    /// An empty buffer holding at most `capacity` transitions (at least one).
    pub fn new(capacity: usize, obs_dim: usize, act_dim: usize) -> Self {
        let capacity = capacity.max(1);
        Replay {
            obs_dim,
            act_dim,
            capacity,
            len: 0,
            next: 0,
            obs: vec![0.0; capacity * obs_dim],
            act: vec![0.0; capacity * act_dim],
            reward: vec![0.0; capacity],
            next_obs: vec![0.0; capacity * obs_dim],
            not_done: vec![0.0; capacity],
            labels: None,
        }
    }

    /// The buffer stores a label (the teacher's action) with every transition, and sampled rows
    /// carry it as their cloning target ([`Batch::bc_target`], all rows counted in
    /// [`Batch::demo_rows`]).
    pub fn with_labels(mut self) -> Self {
        self.labels = Some(vec![0.0; self.capacity * self.act_dim]);
        self
    }

    /// Whether the buffer stores labels.
    pub fn has_labels(&self) -> bool {
        self.labels.is_some()
    }

    /// Transitions stored.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Maximum number of transitions.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Observation and action sizes.
    pub fn dims(&self) -> (usize, usize) {
        (self.obs_dim, self.act_dim)
    }

    /// Stores one transition, overwriting the oldest when full. Slices longer than the dimensions are
    /// cut; shorter ones leave the rest of the slot zero-filled.
    pub fn push(
        &mut self,
        obs: &[f32],
        act: &[f32],
        reward: f32,
        next_obs: &[f32],
        terminal: bool,
    ) {
        self.push_discounted(obs, act, reward, next_obs, if terminal { 0.0 } else { 1.0 });
    }

    /// Stores one transition whose bootstrap multiplier is `not_done` (an n-step row's
    /// `gamma^(n-1)`, 0 after a terminal step).
    pub fn push_discounted(
        &mut self,
        obs: &[f32],
        act: &[f32],
        reward: f32,
        next_obs: &[f32],
        not_done: f32,
    ) {
        let i = self.next;
        copy_row(&mut self.obs, i, self.obs_dim, obs);
        copy_row(&mut self.act, i, self.act_dim, act);
        copy_row(&mut self.next_obs, i, self.obs_dim, next_obs);
        self.reward[i] = reward;
        self.not_done[i] = not_done;
        if let Some(l) = &mut self.labels {
            // Unlabelled pushes (not made by a labelling run) clone the action taken.
            copy_row(l, i, self.act_dim, act);
        }
        self.next = (i + 1) % self.capacity;
        self.len = (self.len + 1).min(self.capacity);
    }

    /// [`Replay::push_discounted`] with the teacher's action `label` at `obs` (ignored by a buffer
    /// without labels).
    pub fn push_labelled(
        &mut self,
        obs: &[f32],
        act: &[f32],
        reward: f32,
        next_obs: &[f32],
        not_done: f32,
        label: &[f32],
    ) {
        let i = self.next;
        self.push_discounted(obs, act, reward, next_obs, not_done);
        if let Some(l) = &mut self.labels {
            copy_row(l, i, self.act_dim, label);
        }
    }

    /// Fills `batch` with `n` transitions drawn uniformly with replacement (`n` is capped by the batch's
    /// capacity). Leaves the batch empty when the buffer is.
    pub fn sample(&self, rng: &mut Rng, n: usize, batch: &mut Batch) {
        batch.demo_rows = 0;
        self.sample_after(rng, 0, n, batch);
    }

    /// Fills rows `from..from + n` of `batch` (capped by its capacity) with uniform draws and sets
    /// `batch.len` to the end of them (rows before `from` are left as they are, e.g. demonstration
    /// rows). Leaves `batch.len = from` when the buffer is empty.
    pub fn sample_after(&self, rng: &mut Rng, from: usize, n: usize, batch: &mut Batch) {
        let end = if self.len == 0 {
            from
        } else {
            (from + n).min(batch.capacity())
        };
        for r in from..end {
            let i = rng.below(self.len);
            self.copy_row_into(i, batch, r);
        }
        batch.len = end;
        if self.labels.is_some() {
            batch.demo_rows = end;
        }
    }

    /// The stored observations (before each step), row-major, oldest slot first.
    pub fn observations(&self) -> &[f32] {
        &self.obs[..self.len * self.obs_dim]
    }

    /// Copies stored transition `i` into row `r` of `batch`.
    pub(crate) fn copy_row_into(&self, i: usize, batch: &mut Batch, r: usize) {
        let (o, a) = (self.obs_dim, self.act_dim);
        batch.obs[r * o..(r + 1) * o].copy_from_slice(&self.obs[i * o..(i + 1) * o]);
        batch.next_obs[r * o..(r + 1) * o].copy_from_slice(&self.next_obs[i * o..(i + 1) * o]);
        batch.act[r * a..(r + 1) * a].copy_from_slice(&self.act[i * a..(i + 1) * a]);
        batch.reward[r] = self.reward[i];
        batch.not_done[r] = self.not_done[i];
        if let Some(l) = &self.labels {
            batch.bc_target[r * a..(r + 1) * a].copy_from_slice(&l[i * a..(i + 1) * a]);
        }
    }

    /// Raw contents for checkpoints: (next slot, stored count, obs, act, reward, next_obs, not_done).
    #[allow(clippy::type_complexity)]
    pub(crate) fn raw(&self) -> (usize, usize, [&[f32]; 5]) {
        (
            self.next,
            self.len,
            [
                &self.obs,
                &self.act,
                &self.reward,
                &self.next_obs,
                &self.not_done,
            ],
        )
    }

    /// The stored labels (`None` without), all slots.
    pub(crate) fn labels(&self) -> Option<&[f32]> {
        self.labels.as_deref()
    }

    /// Restores labels written from [`Replay::labels`]; false without labels or when the size
    /// does not match.
    pub(crate) fn restore_labels(&mut self, labels: Vec<f32>) -> bool {
        match &mut self.labels {
            Some(l) if l.len() == labels.len() => {
                *l = labels;
                true
            }
            _ => false,
        }
    }

    /// Restores contents written by [`Replay::raw`]; false if the sizes do not match this buffer.
    pub(crate) fn restore(&mut self, next: usize, len: usize, fields: [Vec<f32>; 5]) -> bool {
        let [obs, act, reward, next_obs, not_done] = fields;
        if next >= self.capacity
            || len > self.capacity
            || obs.len() != self.obs.len()
            || act.len() != self.act.len()
            || reward.len() != self.reward.len()
            || next_obs.len() != self.next_obs.len()
            || not_done.len() != self.not_done.len()
        {
            return false;
        }
        (self.next, self.len) = (next, len);
        (
            self.obs,
            self.act,
            self.reward,
            self.next_obs,
            self.not_done,
        ) = (obs, act, reward, next_obs, not_done);
        true
    }
}

fn copy_row(dst: &mut [f32], row: usize, dim: usize, src: &[f32]) {
    let slot = &mut dst[row * dim..(row + 1) * dim];
    let n = src.len().min(dim);
    slot[..n].copy_from_slice(&src[..n]);
    slot[n..].fill(0.0);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_overwrites_oldest_and_samples_stored_rows() {
        let mut r = Replay::new(3, 1, 1);
        for i in 0..5 {
            let v = i as f32;
            r.push(&[v], &[v], v, &[v + 1.0], i == 4);
        }
        assert_eq!(r.len(), 3);
        let mut b = Batch::new(16, 1, 1);
        r.sample(&mut Rng::seed_from_u64(0), 16, &mut b);
        assert_eq!(b.len, 16);
        for k in 0..16 {
            assert!(b.obs[k] >= 2.0, "old rows must be gone");
            assert_eq!(b.next_obs[k], b.obs[k] + 1.0);
            assert_eq!(b.not_done[k], if b.obs[k] == 4.0 { 0.0 } else { 1.0 });
        }
        let empty = Replay::new(4, 1, 1);
        empty.sample(&mut Rng::seed_from_u64(0), 4, &mut b);
        assert_eq!(b.len, 0);
    }

    #[test]
    fn labels_follow_their_rows_through_the_ring_and_fill_every_cloning_target() {
        let mut r = Replay::new(3, 1, 2).with_labels();
        for i in 0..7 {
            let v = i as f32;
            r.push_labelled(&[v], &[v, v], 0.0, &[v], 1.0, &[10.0 * v, -v]);
        }
        let mut b = Batch::new(32, 1, 2);
        b.demo_rows = 4;
        r.sample_after(&mut Rng::seed_from_u64(1), 4, 28, &mut b);
        assert_eq!((b.len, b.demo_rows), (32, 32));
        for k in 4..32 {
            let v = b.obs[k];
            assert!(v >= 4.0);
            assert_eq!(b.bc_target[2 * k..2 * k + 2], [10.0 * v, -v]);
        }
        // Without labels nothing changes: the demonstration rows stay the only cloned ones.
        let plain = Replay::new(3, 1, 2);
        let mut b = Batch::new(8, 1, 2);
        b.demo_rows = 2;
        plain.sample_after(&mut Rng::seed_from_u64(1), 2, 6, &mut b);
        assert_eq!(b.demo_rows, 2);
    }
}

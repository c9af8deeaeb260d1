//! The paper's predicates (reach, grasp, stack), its shaping terms and its four reward functions.
//!
//! Choices the paper leaves open (all lengths in metres, in the table frame unless said otherwise):
//! - **reach**: the pinch site lies inside an axis-aligned box of half-lengths [`REACH_HALF_EXTENTS`]
//!   centred [`REACH_CENTRE_HEIGHT`] above brick 1's origin (i.e. around the brick's middle).
//! - **grasp**: brick 1 is lifted *and held*: its origin (bottom face) is more than [`GRASP_HEIGHT`] =
//!   3 cm above the table and within [`GRASP_HOLD_DISTANCE`] = 4 cm of the pinch site (the demonstrator's own "in hand" test). Height alone
//!   also held for a brick tipped onto its end (its origin then sits 3.2 cm up) or leaning on brick 2;
//!   in the hand the origin is 1.2 cm below the pinch site ([`super::scene::GRASP_DEPTH`]).
//! - **stack**: brick 1's origin, minus brick 2's stacking site (brick 2's origin + [`BRICK_HEIGHT`] along
//!   brick 2's z axis), expressed in brick 2's frame, lies inside a box of half-lengths
//!   [`STACK_HALF_EXTENTS`] (1 cm sideways, 8 mm vertically: tolerates a brick resting on the studs).
//! - shaping: `r_S1 = 1 - tanh²(W1 |s_B1 - s_P|)`, `r_S2 = 1 - tanh²(W2 |s_B1 - s_B2|)` with
//!   [`W1`] = [`W2`] = 10 per metre (r = 0.42 at 10 cm, 0.07 at 20 cm), distances between brick origins and
//!   the pinch site.

use super::scene::BRICK_HEIGHT;

/// Half-lengths of the reach box around brick 1 (x, y, z).
pub const REACH_HALF_EXTENTS: [f64; 3] = [0.04, 0.04, 0.04];
/// Height of the reach box's centre above brick 1's origin.
pub const REACH_CENTRE_HEIGHT: f64 = 0.01;
/// Brick 1's origin must be above this height for the grasp predicate.
pub const GRASP_HEIGHT: f64 = 0.03;
/// Brick 1's origin must be within this distance of the pinch site for the grasp predicate.
pub const GRASP_HOLD_DISTANCE: f64 = 0.04;
/// Half-lengths of the stack box, in brick 2's frame (x, y, z).
pub const STACK_HALF_EXTENTS: [f64; 3] = [0.01, 0.01, 0.008];
/// Weight of the pinch-to-brick-1 distance in `r_S1`, per metre.
pub const W1: f64 = 10.0;
/// Weight of the brick-1-to-brick-2 distance in `r_S2`, per metre.
pub const W2: f64 = 10.0;

/// The geometric state the rewards are computed from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RewardState {
    /// Pinch site position.
    pub pinch: [f64; 3],
    /// Brick 1 origin.
    pub brick1_pos: [f64; 3],
    /// Brick 2 origin.
    pub brick2_pos: [f64; 3],
    /// Brick 2 orientation as a row-major rotation matrix (brick frame to table frame).
    pub brick2_mat: [f64; 9],
}

/// Values of the three predicates for one state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Predicates {
    /// Pinch site inside the reach box of brick 1.
    pub reach: bool,
    /// Brick 1 lifted above [`GRASP_HEIGHT`] and held (within [`GRASP_HOLD_DISTANCE`] of the pinch site).
    pub grasp: bool,
    /// Brick 1 inside the stack box of brick 2.
    pub stack: bool,
}

impl RewardState {
    /// Evaluates the reach, grasp and stack predicates.
    pub fn predicates(&self) -> Predicates {
        let centre = [
            self.brick1_pos[0],
            self.brick1_pos[1],
            self.brick1_pos[2] + REACH_CENTRE_HEIGHT,
        ];
        let reach = (0..3).all(|i| (self.pinch[i] - centre[i]).abs() <= REACH_HALF_EXTENTS[i]);
        let grasp = self.brick1_pos[2] > GRASP_HEIGHT
            && dist(&self.brick1_pos, &self.pinch) <= GRASP_HOLD_DISTANCE;
        let d = self.stack_offset();
        let stack = (0..3).all(|i| d[i].abs() <= STACK_HALF_EXTENTS[i]);
        Predicates {
            reach,
            grasp,
            stack,
        }
    }

    /// Brick 1's origin minus brick 2's stacking site, in brick 2's frame.
    pub fn stack_offset(&self) -> [f64; 3] {
        let m = &self.brick2_mat;
        let site = [
            self.brick2_pos[0] + m[2] * BRICK_HEIGHT,
            self.brick2_pos[1] + m[5] * BRICK_HEIGHT,
            self.brick2_pos[2] + m[8] * BRICK_HEIGHT,
        ];
        let w = [
            self.brick1_pos[0] - site[0],
            self.brick1_pos[1] - site[1],
            self.brick1_pos[2] - site[2],
        ];
        // R^T w: columns of R are the brick's axes.
        [
            m[0] * w[0] + m[3] * w[1] + m[6] * w[2],
            m[1] * w[0] + m[4] * w[1] + m[7] * w[2],
            m[2] * w[0] + m[5] * w[1] + m[8] * w[2],
        ]
    }

    /// `r_S1 = 1 - tanh²(W1 |s_B1 - s_P|)`.
    pub fn r_s1(&self) -> f64 {
        1.0 - (W1 * dist(&self.brick1_pos, &self.pinch)).tanh().powi(2)
    }

    /// `r_S2 = 1 - tanh²(W2 |s_B1 - s_B2|)`.
    pub fn r_s2(&self) -> f64 {
        1.0 - (W2 * dist(&self.brick1_pos, &self.brick2_pos))
            .tanh()
            .powi(2)
    }
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// The reward functions. The first four are the paper's; the last two are the sparse rewards of the
/// Grasp and Reach tasks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Reward {
    /// Paper "Stack (sparse)": 1 if stack, else 0.
    SparseStack,
    /// Paper "Grasp shaping": 1 if stack, 0.25 if grasp, else 0.
    GraspShaping,
    /// Paper "Reach and grasp shaping": 1 stack, 0.25 grasp, 0.125 reach, else 0.
    ReachGraspShaping,
    /// Paper "Full composite": 1 stack; 0.25 + 0.25 r_S2 grasp; 0.125 reach; else 0.125 r_S1.
    FullComposite,
    /// Grasp task: 1 if brick 1 is lifted (grasp predicate), else 0.
    SparseGrasp,
    /// Reach task: 1 if the pinch site is in the reach box, else 0.
    SparseReach,
    /// Reach task, dense: 1 if the pinch site is in the reach box, else
    /// `0.5 (1 - tanh²(W_REACH |s_B1 - s_P|))`. Not from the paper: the learner's fast CI task. The
    /// broader scale ([`W_REACH`] = 4/m, r = 0.31 at 20 cm, 0.08 at 40 cm) gives a gradient from every
    /// start height, and the gap between 0.5 and 1 pays for entering the box.
    ReachShaping,
}

/// Scale of [`Reward::ReachShaping`]'s distance term, per metre.
pub const W_REACH: f64 = 4.0;

impl Reward {
    /// All reward functions, for command lines and sweeps.
    pub const ALL: [Reward; 7] = [
        Reward::SparseStack,
        Reward::GraspShaping,
        Reward::ReachGraspShaping,
        Reward::FullComposite,
        Reward::SparseGrasp,
        Reward::SparseReach,
        Reward::ReachShaping,
    ];

    /// The reward for `state`, whose predicates are `p`.
    pub fn evaluate(self, state: &RewardState, p: Predicates) -> f64 {
        match self {
            Reward::SparseStack => f64::from(u8::from(p.stack)),
            Reward::GraspShaping => {
                if p.stack {
                    1.0
                } else if p.grasp {
                    0.25
                } else {
                    0.0
                }
            }
            Reward::ReachGraspShaping => {
                if p.stack {
                    1.0
                } else if p.grasp {
                    0.25
                } else if p.reach {
                    0.125
                } else {
                    0.0
                }
            }
            Reward::FullComposite => {
                if p.stack {
                    1.0
                } else if p.grasp {
                    0.25 + 0.25 * state.r_s2()
                } else if p.reach {
                    0.125
                } else {
                    0.125 * state.r_s1()
                }
            }
            Reward::SparseGrasp => f64::from(u8::from(p.grasp)),
            Reward::SparseReach => f64::from(u8::from(p.reach)),
            Reward::ReachShaping => {
                if p.reach {
                    1.0
                } else {
                    let d = dist(&state.brick1_pos, &state.pinch);
                    0.5 * (1.0 - (W_REACH * d).tanh().powi(2))
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const IDENTITY: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

    /// Bricks 20 cm apart on the table, pinch site 30 cm above brick 1: no predicate holds.
    fn far() -> RewardState {
        RewardState {
            pinch: [0.0, 0.0, 0.3],
            brick1_pos: [0.0, 0.0, 0.0],
            brick2_pos: [0.0, 0.2, 0.0],
            brick2_mat: IDENTITY,
        }
    }

    fn reached() -> RewardState {
        RewardState {
            pinch: [0.03, -0.03, 0.045],
            ..far()
        }
    }

    fn grasped() -> RewardState {
        RewardState {
            pinch: [0.0, 0.0, 0.06],
            brick1_pos: [0.0, 0.0, 0.045],
            ..far()
        }
    }

    fn stacked() -> RewardState {
        // Brick 2 turned 90 degrees about z; brick 1 offset by (+9 mm, -9 mm, +7 mm) in brick 2's frame.
        let m = [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let b2 = [0.05, 0.05, 0.0];
        // brick-2 frame offset (0.009, -0.009, 0.007) -> table frame R*d = (0.009, 0.009, 0.007).
        RewardState {
            pinch: [0.059, 0.059, 0.04],
            brick1_pos: [0.059, 0.059, BRICK_HEIGHT + 0.007],
            brick2_pos: b2,
            brick2_mat: m,
        }
    }

    #[test]
    fn predicate_branches() {
        assert_eq!(far().predicates(), Predicates::default());
        assert_eq!(
            reached().predicates(),
            Predicates {
                reach: true,
                grasp: false,
                stack: false
            }
        );
        assert_eq!(
            grasped().predicates(),
            Predicates {
                reach: true,
                grasp: true,
                stack: false
            }
        );
        let s = stacked();
        let d = s.stack_offset();
        assert!(
            (d[0] - 0.009).abs() < 1e-12
                && (d[1] + 0.009).abs() < 1e-12
                && (d[2] - 0.007).abs() < 1e-12
        );
        assert!(s.predicates().stack);
    }

    #[test]
    fn grasp_needs_the_brick_held() {
        // Brick 1 tipped onto its end on the table: its origin (bottom-face centre) sits half the
        // brick's length up, above 3 cm, but the hand is far away.
        let tipped = RewardState {
            brick1_pos: [0.0, 0.0, super::super::scene::BRICK_HALF_EXTENTS[1]],
            ..far()
        };
        assert!(tipped.brick1_pos[2] > GRASP_HEIGHT);
        assert!(!tipped.predicates().grasp, "a tipped brick is not grasped");
        // Brick 1 leaning on brick 2, 4 cm up, the hand 5 cm away.
        let leaning = RewardState {
            pinch: [0.0, 0.15, 0.09],
            brick1_pos: [0.0, 0.15, 0.04],
            ..far()
        };
        assert!(
            !leaning.predicates().grasp,
            "a leaning brick is not grasped"
        );
        let mut held = leaning;
        held.pinch = [0.0, 0.15, 0.04 + 0.012];
        assert!(held.predicates().grasp, "held at the grasp depth");
        held.pinch[2] = 0.04 + GRASP_HOLD_DISTANCE + 0.001;
        assert!(!held.predicates().grasp, "just out of the hand");
    }

    #[test]
    fn box_edges() {
        let mut s = reached();
        s.pinch[0] = 0.041;
        assert!(!s.predicates().reach, "just outside the reach box in x");
        s.pinch[0] = 0.0;
        s.pinch[2] = REACH_CENTRE_HEIGHT + 0.041;
        assert!(!s.predicates().reach, "just above the reach box");
        let mut g = grasped();
        g.brick1_pos[2] = 0.0299;
        assert!(!g.predicates().grasp);
        let mut st = stacked();
        st.brick1_pos[2] = BRICK_HEIGHT + 0.0085;
        assert!(!st.predicates().stack, "too high above the stacking site");
        let mut st = stacked();
        // 11 mm along brick 2's x axis, which is the table's y axis after the 90 degree turn.
        st.brick1_pos = [0.05, 0.05 + 0.011, BRICK_HEIGHT];
        assert!(!st.predicates().stack);
        st.brick1_pos = [0.05 - 0.011, 0.05, BRICK_HEIGHT];
        assert!(!st.predicates().stack);
        st.brick1_pos = [0.05 - 0.0099, 0.05 + 0.0099, BRICK_HEIGHT];
        assert!(st.predicates().stack);
    }

    #[test]
    fn shaping_terms() {
        let s = far();
        // r_S1 at 0.3 m: 1 - tanh(3)^2
        assert!((s.r_s1() - (1.0 - 3.0f64.tanh().powi(2))).abs() < 1e-12);
        assert!((s.r_s2() - (1.0 - 2.0f64.tanh().powi(2))).abs() < 1e-12);
        let at = RewardState {
            pinch: s.brick1_pos,
            brick2_pos: s.brick1_pos,
            ..s
        };
        assert_eq!(at.r_s1(), 1.0);
        assert_eq!(at.r_s2(), 1.0);
    }

    #[test]
    fn reward_branches() {
        use Reward::*;
        let cases = [far(), reached(), grasped(), stacked()];
        let expect = |r: Reward| -> [f64; 4] {
            let f = far();
            let g = grasped();
            match r {
                SparseStack => [0.0, 0.0, 0.0, 1.0],
                GraspShaping => [0.0, 0.0, 0.25, 1.0],
                ReachGraspShaping => [0.0, 0.125, 0.25, 1.0],
                FullComposite => [0.125 * f.r_s1(), 0.125, 0.25 + 0.25 * g.r_s2(), 1.0],
                SparseGrasp => [0.0, 0.0, 1.0, 0.0],
                SparseReach => [0.0, 1.0, 1.0, 1.0],
                // 30 cm from brick 1: 0.5 (1 - tanh²(1.2)) = 0.5 (1 - 0.83365...^2).
                ReachShaping => [0.5 * (1.0 - (1.2f64).tanh().powi(2)), 1.0, 1.0, 1.0],
            }
        };
        for r in Reward::ALL {
            let got: Vec<f64> = cases
                .iter()
                .map(|s| r.evaluate(s, s.predicates()))
                .collect();
            assert_eq!(got, expect(r), "{r:?}");
        }
        // The stacked case also satisfies grasp (brick 1 is above 3 cm) only if it is high enough: it is
        // not here (origin at 2.6 cm), which is why SparseGrasp is 0 there.
        assert!(!stacked().predicates().grasp);
    }
}

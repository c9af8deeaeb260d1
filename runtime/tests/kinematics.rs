//! The envelope's forward kinematics ([`pinch_position_trig`] on [`JointTrig`]) against the
//! quaternion chain ([`pinch_pose`]) and an f64 reference of the same constants, on many seeded
//! random angle sets and offsets.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_runtime::jaco_kinematics::{CHAIN, SITE_POS};
use dex_runtime::kinematics::{
    ARM_JOINTS, JointTrig, SIN_COS_RANGE, pinch_pose, pinch_position_trig, sin_cos,
};

/// The pinch site's position in f64: the chain's (f32) constants, exact trigonometry.
fn reference(q: &[f64; ARM_JOINTS]) -> [f64; 3] {
    // Quaternion products in f64: (w, x, y, z).
    fn mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
        [
            a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
            a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
            a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
            a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
        ]
    }
    fn rotate(r: [f64; 4], v: [f64; 3]) -> [f64; 3] {
        let p = mul(mul(r, [0.0, v[0], v[1], v[2]]), [r[0], -r[1], -r[2], -r[3]]);
        [p[1], p[2], p[3]]
    }
    fn unit(q: [f32; 4]) -> [f64; 4] {
        let q = q.map(f64::from);
        let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
        q.map(|x| x / n)
    }
    let mut pos = [0.0f64; 3];
    let mut rot = [1.0, 0.0, 0.0, 0.0];
    for link in &CHAIN {
        let d = rotate(rot, link.pos.map(f64::from));
        pos = [pos[0] + d[0], pos[1] + d[1], pos[2] + d[2]];
        rot = mul(rot, unit(link.quat));
        if let Some(k) = link.joint {
            let (s, c) = (0.5 * q[k]).sin_cos();
            let a = link.axis.map(f64::from);
            rot = mul(rot, [c, a[0] * s, a[1] * s, a[2] * s]);
        }
    }
    let d = rotate(rot, SITE_POS.map(f64::from));
    [pos[0] + d[0], pos[1] + d[1], pos[2] + d[2]]
}

fn distance(a: &[f32], b: &[f64; 3]) -> f64 {
    (0..3)
        .map(|i| (f64::from(a[i]) - b[i]).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// A seeded generator of uniform f32 values (splitmix64).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [-r, r].
    fn angles(&mut self, r: f32) -> [f32; ARM_JOINTS] {
        core::array::from_fn(|_| ((self.next() >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0) * r)
    }
}

/// Worst distances over 20,000 seeded angle sets in [-2 pi, 2 pi]: the envelope's chain against
/// the f64 reference and against [`pinch_pose`].
#[test]
fn matrix_chain_matches_the_quaternion_chain_and_the_f64_reference() {
    let mut rng = Rng(7);
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    for _ in 0..20_000 {
        let q = rng.angles(6.3);
        let trig = pinch_position_trig(&JointTrig::of(&q));
        let quat = pinch_pose(&q).pos;
        let exact = reference(&q.map(f64::from));
        worst.0 = worst.0.max(distance(trig.as_slice(), &exact));
        worst.1 = worst.1.max(distance(quat.as_slice(), &exact));
        worst.2 = worst
            .2
            .max(distance(trig.as_slice(), &quat.map(f64::from).into()));
    }
    println!(
        "matrix chain vs f64 {:.3e} m, quaternion chain vs f64 {:.3e} m, matrix vs quaternion {:.3e} m",
        worst.0, worst.1, worst.2
    );
    assert!(worst.0 < 1.0e-6, "matrix chain vs f64: {:e} m", worst.0);
    assert!(
        worst.2 < 2.0e-6,
        "matrix vs quaternion chain: {:e} m",
        worst.2
    );
}

/// The angles `q + d` by angle addition from `q`'s sines and cosines, for small offsets (a period
/// at full speed: |d| <= 0.2) and large ones (|d| <= 40, braking from a synthetic trace's
/// velocities): within 1e-6 m of the f64 reference at the unrounded angle `q + d`.
#[test]
fn shifted_angles_match_the_reference_at_the_unrounded_angle() {
    let mut rng = Rng(8);
    let mut worst = [0.0f64; 2];
    let mut trig_err = 0.0f64;
    for _ in 0..20_000 {
        let q = rng.angles(6.3);
        let base = JointTrig::of(&q);
        for (i, d) in [rng.angles(0.2), rng.angles(40.0)].iter().enumerate() {
            let t = base.shifted(d);
            let angle: [f64; ARM_JOINTS] =
                core::array::from_fn(|j| f64::from(q[j]) + f64::from(d[j]));
            for (j, a) in angle.iter().enumerate() {
                let (s, c) = a.sin_cos();
                trig_err = trig_err
                    .max((f64::from(t.sin[j]) - s).abs())
                    .max((f64::from(t.cos[j]) - c).abs());
            }
            let got = pinch_position_trig(&t);
            worst[i] = worst[i].max(distance(got.as_slice(), &reference(&angle)));
        }
    }
    println!(
        "shifted: small offsets {:.3e} m, large offsets {:.3e} m, sine/cosine {:.3e}",
        worst[0], worst[1], trig_err
    );
    assert!(worst[0] < 1.0e-6 && worst[1] < 1.0e-6, "{worst:?}");
    assert!(trig_err < 5.0e-7, "sine/cosine error {trig_err:e}");
}

/// [`sin_cos`] against f64 on a fine grid of [-SIN_COS_RANGE, SIN_COS_RANGE] (5.1 million points,
/// every quadrant boundary crossed): within 1.5e-7 (the f32 ulp of values in [0.5, 1) is 6e-8),
/// and `libm::sinf`/`libm::cosf` past the range.
#[test]
fn f32_sin_cos_is_within_1_5e_7() {
    let n = 5_120_000;
    let mut worst = (0.0f64, 0.0f32);
    for i in 0..=n {
        let x = -SIN_COS_RANGE + 2.0 * SIN_COS_RANGE * (i as f32 / n as f32);
        let (s, c) = sin_cos(x);
        let (es, ec) = f64::from(x).sin_cos();
        let e = (f64::from(s) - es).abs().max((f64::from(c) - ec).abs());
        if e > worst.0 {
            worst = (e, x);
        }
    }
    println!("sin_cos worst error {:.3e} at {}", worst.0, worst.1);
    assert!(worst.0 <= 1.5e-7, "{worst:?}");
    for x in [257.0, -300.0, 1.0e6, f32::INFINITY] {
        let (s, c) = sin_cos(x);
        assert_eq!(
            (s.to_bits(), c.to_bits()),
            (libm::sinf(x).to_bits(), libm::cosf(x).to_bits())
        );
    }
    assert!(sin_cos(f32::NAN).0.is_nan());
    assert_eq!(sin_cos(0.0), (0.0, 1.0));
}

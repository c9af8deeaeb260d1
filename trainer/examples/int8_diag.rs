//! Diagnosis of the int8 error of a trained policy (f64 simulation of the quantiser, see
//! docs/benchmarks.md "int8 policies"): equalisation variants, GPTQ, mixed precision, weight bits.
//! `cargo run --release -p dex-trainer --example int8_diag -- trainer/tests/fixtures/reach_seed0.dxpl`
#![allow(
    clippy::all,
    clippy::pedantic,
    clippy::unwrap_used,
    clippy::expect_used,
    missing_docs
)]
use dex_policy::PolicyView;
use dex_runtime::testkit::aligned_copy;
use dex_trainer::env::{EnvConfig, Scene, Task};
use dex_trainer::evaluate::{HELDOUT_SEED, heldout_observations};

#[derive(Clone)]
struct L {
    ni: usize,
    no: usize,
    w: Vec<f64>,
    b: Vec<f64>,
}
#[derive(Clone)]
struct Net {
    mu: Vec<f64>,
    sg: Vec<f64>,
    ls: Vec<L>,
}

fn fwd(net: &Net, o: &[f32], aq: bool, acts: &mut Option<&mut Vec<Vec<Vec<f64>>>>) -> Vec<f64> {
    let mut x: Vec<f64> = o
        .iter()
        .enumerate()
        .map(|(i, &v)| (f64::from(v) - net.mu[i]) / net.sg[i])
        .collect();
    let nl = net.ls.len();
    for (k, l) in net.ls.iter().enumerate() {
        if aq {
            let m = x.iter().fold(0f64, |m, y| m.max(y.abs()));
            let sx = if m > 0.0 { m / 32767.0 } else { 1.0 };
            x.iter_mut().for_each(|t| *t = (*t / sx).round() * sx);
        }
        if let Some(a) = acts.as_mut() {
            a[k].push(x.clone());
        }
        let mut y = l.b.clone();
        for i in 0..l.ni {
            let xi = x[i];
            for j in 0..l.no {
                y[j] += l.w[i * l.no + j] * xi;
            }
        }
        if k + 1 < nl {
            y.iter_mut().for_each(|t| *t = t.max(0.0));
        } else {
            y.iter_mut().for_each(|t| *t = t.tanh());
        }
        x = y;
    }
    x
}

fn quant(l: &L, hess: Option<&Vec<Vec<f64>>>) -> L {
    let (ni, no) = (l.ni, l.no);
    let mut out = l.clone();
    // scales
    let sc: Vec<f64> = (0..no)
        .map(|j| {
            let m = (0..ni).fold(0f64, |m, i| m.max(l.w[i * no + j].abs()));
            if m > 0.0 { m / 127.0 } else { 1.0 }
        })
        .collect();
    match hess {
        None => {
            for i in 0..ni {
                for j in 0..no {
                    let s = sc[j];
                    out.w[i * no + j] = (l.w[i * no + j] / s).round().clamp(-127.0, 127.0) * s;
                }
            }
        }
        Some(h) => {
            // GPTQ: Hinv upper cholesky
            let mut h = h.clone();
            let damp = 0.01 * (0..ni).map(|i| h[i][i]).sum::<f64>() / ni as f64;
            for i in 0..ni {
                h[i][i] += damp.max(1e-12);
            }
            let hinv = inv(&h);
            let u = chol_upper(&hinv);
            let mut w = l.w.clone();
            for i in 0..ni {
                for j in 0..no {
                    let s = sc[j];
                    let q = (w[i * no + j] / s).round().clamp(-127.0, 127.0) * s;
                    let e = (w[i * no + j] - q) / u[i][i];
                    out.w[i * no + j] = q;
                    for k in i + 1..ni {
                        w[k * no + j] -= e * u[i][k];
                    }
                }
            }
        }
    }
    out
}
fn inv(a: &Vec<Vec<f64>>) -> Vec<Vec<f64>> {
    let n = a.len();
    let mut m: Vec<Vec<f64>> = a
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let mut r = r.clone();
            r.extend((0..n).map(|k| if k == i { 1.0 } else { 0.0 }));
            r
        })
        .collect();
    for c in 0..n {
        let p = (c..n)
            .max_by(|&x, &y| m[x][c].abs().partial_cmp(&m[y][c].abs()).unwrap())
            .unwrap();
        m.swap(c, p);
        let d = m[c][c];
        for k in 0..2 * n {
            m[c][k] /= d;
        }
        for r in 0..n {
            if r != c {
                let f = m[r][c];
                if f != 0.0 {
                    for k in 0..2 * n {
                        m[r][k] -= f * m[c][k];
                    }
                }
            }
        }
    }
    m.into_iter().map(|r| r[n..].to_vec()).collect()
}
fn chol_upper(a: &Vec<Vec<f64>>) -> Vec<Vec<f64>> {
    // A = U^T U
    let n = a.len();
    let mut u = vec![vec![0f64; n]; n];
    for i in 0..n {
        let mut s = a[i][i];
        for k in 0..i {
            s -= u[k][i] * u[k][i];
        }
        u[i][i] = s.max(1e-300).sqrt();
        for j in i + 1..n {
            let mut s = a[i][j];
            for k in 0..i {
                s -= u[k][i] * u[k][j];
            }
            u[i][j] = s / u[i][i];
        }
    }
    u
}

fn main() {
    let path = std::env::args().nth(1).unwrap();
    let file = std::fs::read(path).unwrap();
    let a = aligned_copy(&file);
    let view = PolicyView::decode(a.as_bytes()).unwrap();
    let v = view.values().as_slice().unwrap();
    let n = view.body().obs_dim();
    let mut net = Net {
        mu: v[..n].iter().map(|&x| f64::from(x)).collect(),
        sg: v[n..2 * n].iter().map(|&x| f64::from(x)).collect(),
        ls: vec![],
    };
    for l in view.layers() {
        net.ls.push(L {
            ni: l.inputs,
            no: l.outputs,
            w: v[l.weights..l.weights + l.inputs * l.outputs]
                .iter()
                .map(|&x| f64::from(x))
                .collect(),
            b: v[l.biases..l.biases + l.outputs]
                .iter()
                .map(|&x| f64::from(x))
                .collect(),
        });
    }
    let scene = Scene::load().unwrap();
    let env = EnvConfig::new(Task::Reach);
    let held = heldout_observations(&file, &scene, env, 10, HELDOUT_SEED).unwrap();
    let calib = heldout_observations(&file, &scene, env, 20, 8_000_000).unwrap();
    let joints = &view.body().action;
    let err = |q: &Net, aq: bool| -> Vec<f64> {
        let mut e = vec![0f64; 9];
        for o in &held {
            let f = fwd(&net, o, false, &mut None);
            let g = fwd(q, o, aq, &mut None);
            for j in 0..9 {
                let (sc, lo, hi) = (
                    f64::from(joints[j].scale),
                    f64::from(joints[j].min),
                    f64::from(joints[j].max),
                );
                e[j] = e[j]
                    .max(((f[j] * sc).clamp(lo, hi) - (g[j] * sc).clamp(lo, hi)).abs() / (hi - lo));
            }
        }
        e
    };
    let show = |name: &str, e: Vec<f64>| {
        println!(
            "{name:40} worst {:7.3}% {:?}",
            e.iter().cloned().fold(0.0, f64::max) * 100.0,
            e.iter()
                .map(|x| (x * 1000.0).round() / 10.0)
                .collect::<Vec<_>>()
        )
    };
    let quant_all = |m: &Net, gptq: bool| -> Net {
        let mut q = m.clone();
        for k in 0..m.ls.len() {
            let h = if gptq {
                // inputs of layer k from the (already quantised) network q, activation quant on
                let mut acts = vec![vec![]; m.ls.len()];
                for o in &calib {
                    fwd(&q, o, true, &mut Some(&mut acts));
                }
                let ni = m.ls[k].ni;
                let mut h = vec![vec![0f64; ni]; ni];
                for x in &acts[k] {
                    for i in 0..ni {
                        for j in 0..ni {
                            h[i][j] += x[i] * x[j];
                        }
                    }
                }
                Some(h)
            } else {
                None
            };
            q.ls[k] = quant(&m.ls[k], h.as_ref());
        }
        q
    };
    show("rtn", err(&quant_all(&net, false), true));
    show("gptq", err(&quant_all(&net, true), true));
    // fold inputs
    let mut f = net.clone();
    {
        let mut lo = vec![f64::MAX; n];
        let mut hi = vec![f64::MIN; n];
        for o in &calib {
            for i in 0..n {
                let z = (f64::from(o[i]) - f.mu[i]) / f.sg[i];
                lo[i] = lo[i].min(z);
                hi[i] = hi[i].max(z);
            }
        }
        let l0 = &mut f.ls[0];
        for i in 0..n {
            let m = 0.5 * (lo[i] + hi[i]);
            let r = (0.5 * (hi[i] - lo[i])).max(1e-2);
            f.mu[i] += f.sg[i] * m;
            f.sg[i] *= r;
            for j in 0..l0.no {
                l0.b[j] += l0.w[i * l0.no + j] * m;
                l0.w[i * l0.no + j] *= r;
            }
        }
    }
    show("fold f32 (should be 0)", err(&f, false));
    show("fold rtn", err(&quant_all(&f, false), true));
    show("fold gptq", err(&quant_all(&f, true), true));
    // CLE on hidden layers
    let mut c = f.clone();
    for k in 0..c.ls.len() - 1 {
        let (a, b) = {
            let (x, y) = c.ls.split_at_mut(k + 1);
            (&mut x[k], &mut y[0])
        };
        for j in 0..a.no {
            let r1 = (0..a.ni).fold(0f64, |m, i| m.max(a.w[i * a.no + j].abs()));
            let r2 = (0..b.no).fold(0f64, |m, t| m.max(b.w[j * b.no + t].abs()));
            if r1 > 0.0 && r2 > 0.0 {
                let s = (r1 / r2).sqrt(); // scale out j by 1/s, row j by s
                for i in 0..a.ni {
                    a.w[i * a.no + j] /= s;
                }
                a.b[j] /= s;
                for t in 0..b.no {
                    b.w[j * b.no + t] *= s;
                }
            }
        }
    }
    show("fold+cle f32", err(&c, false));
    show("fold+cle rtn", err(&quant_all(&c, false), true));
    show("fold+cle gptq", err(&quant_all(&c, true), true));
    // activation-aware row scale (per layer k>=1 rows scaled by sqrt(mean|x|)... )
    for keep in 0..3 {
        let mut q = quant_all(&f, true);
        q.ls[keep] = f.ls[keep].clone();
        show(&format!("fold gptq keep {keep} f32"), err(&q, true));
    }

    for keep in [[0usize, 1usize], [0, 2], [1, 2]] {
        let mut q = quant_all(&f, false);
        for &k in &keep {
            q.ls[k] = f.ls[k].clone();
        }
        show(&format!("fold rtn keep {keep:?} f32"), err(&q, true));
    }
    // bits sweep: RTN per-channel with 2^(bits-1)-1 levels
    for bits in [8u32, 10, 12, 14, 16] {
        let lv = f64::from((1u32 << (bits - 1)) - 1);
        let mut q = f.clone();
        for l in q.ls.iter_mut() {
            for j in 0..l.no {
                let m = (0..l.ni).fold(0f64, |m, i| m.max(l.w[i * l.no + j].abs()));
                let s = if m > 0.0 { m / lv } else { 1.0 };
                for i in 0..l.ni {
                    l.w[i * l.no + j] = (l.w[i * l.no + j] / s).round() * s;
                }
            }
        }
        show(&format!("fold rtn {bits} bits"), err(&q, true));
    }
    // percentiles of the int8 rtn error
    let q = quant_all(&f, false);
    let mut all = vec![];
    for o in &held {
        let a = fwd(&f, o, false, &mut None);
        let b = fwd(&q, o, true, &mut None);
        for j in 0..9 {
            let (sc, lo, hi) = (
                f64::from(joints[j].scale),
                f64::from(joints[j].min),
                f64::from(joints[j].max),
            );
            all.push(((a[j] * sc).clamp(lo, hi) - (b[j] * sc).clamp(lo, hi)).abs() / (hi - lo));
        }
    }
    all.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let p = |q: f64| all[((all.len() - 1) as f64 * q) as usize] * 100.0;
    println!(
        "fold rtn error percentiles (% of range): p50 {:.3} p90 {:.3} p99 {:.3} max {:.3}; share > 1%: {:.1}%",
        p(0.5),
        p(0.9),
        p(0.99),
        p(1.0),
        all.iter().filter(|&&e| e > 0.01).count() as f64 * 100.0 / all.len() as f64
    );
}

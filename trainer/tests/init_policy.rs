//! Starting the learner's actor from an exported policy file (`init_policy`, `--init-policy`):
//! the imported actor computes what the file computes, and a file of another task, precision,
//! shape or a corrupt one is refused with a clear error before any training. Also the paper
//! protocol's other settings refused before training (issue #27): R = 0, training episodes longer
//! than the evaluation's, a demonstrator policy of another task.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_trainer::env::Task;
use dex_trainer::files::export::{ExportInfo, ObsNormalisation, Precision, export_actor_with};
use dex_trainer::files::policy_import::{
    ImportError, actor_params_from_policy, normalised_actor_from_policy,
};
use dex_trainer::learn::nets::{Activation, Mlp, MlpSpec};
use dex_trainer::learn::{DdpgConfig, Engine, Rng, RunConfig, Trainer};
use dex_trainer::pipeline::train_run::{TrainPlan, TrainRunError};
use dex_trainer::pipeline::train_settings::{SettingsError, TaskArg, TrainSettings};

fn config(hidden: &[usize]) -> RunConfig {
    RunConfig {
        ddpg: DdpgConfig {
            actor_hidden: hidden.to_vec(),
            critic_hidden: vec![8],
            ..DdpgConfig::default()
        },
        ..RunConfig::default()
    }
}

/// A trainer whose 44-16-16-9 actor has random (not near-zero) weights.
fn random_actor(seed: u64) -> Trainer {
    random_actor_of(OBS_DIM, &mut Rng::seed_from_u64(seed))
}

/// A trainer whose 16-16-9 actor on `inputs` inputs has random weights drawn from `rng`.
fn random_actor_of(inputs: usize, rng: &mut Rng) -> Trainer {
    let mut t = Trainer::new(config(&[16, 16]), inputs, ACT_DIM).unwrap();
    let params: Vec<f32> = (0..t.actor().0.num_params())
        .map(|_| rng.uniform(-0.4, 0.4))
        .collect();
    t.set_initial_actor(params).unwrap();
    t
}

struct Exported {
    file: Vec<u8>,
    mean: Vec<f32>,
    inv_std: Vec<f32>,
}

impl Exported {
    /// What the file's network sees for the raw observation `x`: `(x - mean) * inv_std`.
    fn normalise(&self, x: &[f32]) -> Vec<f32> {
        x.iter()
            .zip(&self.mean)
            .zip(&self.inv_std)
            .map(|((x, m), k)| (x - m) * k)
            .collect()
    }
}

fn export(t: &Trainer, task: Task, precision: Precision) -> Exported {
    let mut rng = Rng::seed_from_u64(5);
    let mean: Vec<f32> = (0..OBS_DIM).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let inv_std: Vec<f32> = (0..OBS_DIM).map(|_| rng.uniform(0.5, 3.0)).collect();
    let (net, params) = t.actor();
    let info = ExportInfo::bare(task);
    let file = export_actor_with(
        net,
        params,
        Some(ObsNormalisation {
            mean: &mean,
            inv_std: &inv_std,
        }),
        &info,
        precision,
    )
    .unwrap();
    Exported {
        file,
        mean,
        inv_std,
    }
}

#[test]
fn an_imported_actor_computes_what_the_file_computes() {
    let original = random_actor(1);
    let e = export(&original, Task::Grasp, Precision::F32);
    let params = actor_params_from_policy(&e.file, Task::Grasp, original.actor().0).unwrap();
    let mut imported = Trainer::new(config(&[16, 16]), OBS_DIM, ACT_DIM).unwrap();
    imported.set_initial_actor(params).unwrap();
    let mut rng = Rng::seed_from_u64(9);
    let mut worst = 0.0f32;
    let mut moved = 0.0f32;
    for _ in 0..200 {
        let x: Vec<f32> = (0..OBS_DIM).map(|_| rng.uniform(-2.0, 2.0)).collect();
        // The file: normalise, then the original network.
        let z = e.normalise(&x);
        let (mut want, mut got, mut raw) = ([0.0; ACT_DIM], [0.0; ACT_DIM], [0.0; ACT_DIM]);
        original.act(&z, &mut want).unwrap();
        imported.act(&x, &mut got).unwrap();
        original.act(&x, &mut raw).unwrap();
        for j in 0..ACT_DIM {
            worst = worst.max((want[j] - got[j]).abs());
            moved = moved.max((want[j] - raw[j]).abs());
        }
    }
    assert!(
        worst < 1e-4,
        "imported actor differs from the file by {worst}"
    );
    // The normalisation matters: skipping it would change the actions.
    assert!(
        moved > 0.05,
        "the test's normalisation is too weak ({moved})"
    );
}

#[test]
fn a_normalised_import_keeps_the_files_normaliser_frozen_and_computes_the_same() {
    let original = random_actor(4);
    let e = export(&original, Task::Grasp, Precision::F32);
    let a = normalised_actor_from_policy(&e.file, Task::Grasp, original.actor().0).unwrap();
    // The layers are the file's, bit for bit (nothing folded).
    assert_eq!(a.params, original.actor().1);
    assert_eq!(a.mean, e.mean);
    let mut cfg = config(&[16, 16]);
    cfg.obs_norm.enabled = true;
    // Without frozen_from_init the run would move the normaliser: refused.
    let mut t = Trainer::new(cfg.clone(), OBS_DIM, ACT_DIM).unwrap();
    assert!(
        t.set_initial_actor_normalised(a.params.clone(), &a.mean, &a.inv_std)
            .is_err()
    );
    cfg.obs_norm.frozen_from_init = true;
    let mut t = Trainer::new(cfg, OBS_DIM, ACT_DIM).unwrap();
    t.set_initial_actor_normalised(a.params.clone(), &a.mean, &a.inv_std)
        .unwrap();
    let n = t.obs_normalizer().expect("normaliser");
    for (got, want) in n.inv_std.iter().zip(&e.inv_std) {
        assert!((got - want).abs() <= 1e-6 * want, "{got} vs {want}");
    }
    let mut rng = Rng::seed_from_u64(10);
    let mut worst = 0.0f32;
    for _ in 0..200 {
        let x: Vec<f32> = (0..OBS_DIM).map(|_| rng.uniform(-2.0, 2.0)).collect();
        let z = e.normalise(&x);
        let (mut want, mut got) = ([0.0; ACT_DIM], [0.0; ACT_DIM]);
        original.act(&z, &mut want).unwrap();
        t.act(&x, &mut got).unwrap();
        for j in 0..ACT_DIM {
            worst = worst.max((want[j] - got[j]).abs());
        }
    }
    assert!(
        worst < 1e-4,
        "normalised import differs from the file by {worst}"
    );
    // A scale below the normaliser's floor would be changed by it: refused.
    let mut tiny = a.inv_std.clone();
    tiny[0] = 1e4;
    let mut cfg = config(&[16, 16]);
    cfg.obs_norm.enabled = true;
    cfg.obs_norm.frozen_from_init = true;
    let mut t = Trainer::new(cfg, OBS_DIM, ACT_DIM).unwrap();
    assert!(
        t.set_initial_actor_normalised(a.params, &a.mean, &tiny)
            .is_err()
    );
}

#[test]
fn files_that_cannot_start_the_actor_are_refused_with_the_reason() {
    let t = random_actor(2);
    let actor = t.actor().0;
    let e = export(&t, Task::Stack, Precision::F32);
    let err = actor_params_from_policy(&e.file, Task::Grasp, actor).unwrap_err();
    assert!(matches!(err, ImportError::Task { .. }), "{err}");
    assert!(err.to_string().contains("Stack"), "{err}");

    let int8 = export(&t, Task::Grasp, Precision::Int8);
    let err = actor_params_from_policy(&int8.file, Task::Grasp, actor).unwrap_err();
    assert!(matches!(err, ImportError::NotF32 { layer: 0 }), "{err}");

    let narrow = Mlp::new(
        MlpSpec::stack(
            OBS_DIM,
            &[8, 8],
            Activation::Relu,
            false,
            ACT_DIM,
            Activation::Tanh,
        ),
        Engine::default(),
    )
    .unwrap();
    let good = export(&t, Task::Grasp, Precision::F32);
    let err = actor_params_from_policy(&good.file, Task::Grasp, &narrow).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, ImportError::Shape { .. }), "{msg}");
    assert!(
        msg.contains("44-16 relu-16 relu-9 tanh") && msg.contains("44-8 relu-8 relu-9 tanh"),
        "{msg}"
    );

    let normed = Mlp::new(
        MlpSpec::stack(
            OBS_DIM,
            &[16, 16],
            Activation::Relu,
            true,
            ACT_DIM,
            Activation::Tanh,
        ),
        Engine::default(),
    )
    .unwrap();
    let err = actor_params_from_policy(&good.file, Task::Grasp, &normed).unwrap_err();
    assert!(matches!(err, ImportError::LayerNorm), "{err}");

    let mut corrupt = good.file.clone();
    let mid = corrupt.len() / 2;
    corrupt[mid] ^= 0x40;
    let err = actor_params_from_policy(&corrupt, Task::Grasp, actor).unwrap_err();
    assert!(matches!(err, ImportError::Format(_)), "{err}");

    // A run whose actor has already moved, or parameters of another length, are refused.
    let mut fresh = Trainer::new(config(&[16, 16]), OBS_DIM, ACT_DIM).unwrap();
    assert!(fresh.set_initial_actor(vec![0.0; 3]).is_err());
}

#[test]
fn a_run_naming_a_bad_initial_policy_fails_before_training() {
    let dir = std::env::temp_dir().join(format!("dex-init-policy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let stack = dir.join("stack.dxpl");
    std::fs::write(
        &stack,
        export(&random_actor(3), Task::Stack, Precision::F32).file,
    )
    .unwrap();
    let settings = TrainSettings {
        task: TaskArg::Grasp,
        out: dir.join("run"),
        init_policy: Some(stack.clone()),
        run: config(&[16, 16]),
        ..TrainSettings::default()
    };
    let err = TrainPlan::new(settings.clone()).err().expect("refused");
    assert!(
        matches!(&err, TrainRunError::InitPolicy { path, source: ImportError::Task { .. } } if *path == stack),
        "{err}"
    );
    let missing = TrainSettings {
        init_policy: Some(dir.join("missing.dxpl")),
        ..settings.clone()
    };
    assert!(matches!(
        TrainPlan::new(missing).err(),
        Some(TrainRunError::InitRead { .. })
    ));
    let mut normed = settings.clone();
    normed.run.obs_norm.enabled = true;
    assert!(matches!(
        TrainPlan::new(normed).err(),
        Some(TrainRunError::Settings(SettingsError::InitPolicyNorm))
    ));
    // frozen_from_init without an initial policy is refused; with one it plans a run.
    let mut orphan = TrainSettings {
        init_policy: None,
        ..settings.clone()
    };
    orphan.run.obs_norm.enabled = true;
    orphan.run.obs_norm.frozen_from_init = true;
    assert!(matches!(
        TrainPlan::new(orphan).err(),
        Some(TrainRunError::Settings(SettingsError::InitPolicyNorm))
    ));
    let mut kept = TrainSettings {
        task: TaskArg::Stack,
        ..settings.clone()
    };
    kept.run.obs_norm.enabled = true;
    kept.run.obs_norm.frozen_from_init = true;
    assert!(TrainPlan::new(kept).is_ok());
    // The same file for its own task plans a run; nothing was written yet.
    let ok = TrainSettings {
        task: TaskArg::Stack,
        ..settings
    };
    assert!(TrainPlan::new(ok).is_ok());
    assert!(!dir.join("run").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_paper_protocols_bad_settings_are_refused_before_training() {
    let dir = std::env::temp_dir().join(format!("dex-protocol-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut settings = TrainSettings {
        task: TaskArg::Stack,
        out: dir.join("run"),
        ..TrainSettings::default()
    };
    settings.start.scheme = dex_trainer::pipeline::train_settings::StartArg::AlongDemonstrations;
    // R = 0.
    let mut r0 = settings.clone();
    r0.run.updates_per_step = 0;
    let err = TrainPlan::new(r0).err().expect("refused");
    assert!(
        err.to_string().contains("updates_per_step")
            || format!("{err:?}").contains("updates_per_step"),
        "{err:?}"
    );
    // Training episodes longer than the 150-step evaluation episodes.
    let mut long = settings.clone();
    long.start.train_episode_steps = 151;
    assert!(matches!(
        TrainPlan::new(long).err(),
        Some(TrainRunError::Settings(
            SettingsError::TrainEpisodeTooLong {
                train: 151,
                eval: 150
            }
        ))
    ));
    let mut full = settings.clone();
    full.start.train_episode_steps = 150;
    assert!(TrainPlan::new(full).is_ok());
    // A demonstrator policy of another task.
    let grasp = dir.join("grasp.dxpl");
    std::fs::write(
        &grasp,
        export(&random_actor(5), Task::Grasp, Precision::F32).file,
    )
    .unwrap();
    let mut other = settings.clone();
    other.start.demonstrator_policy = Some(grasp.clone());
    let err = TrainPlan::new(other).err().expect("refused");
    assert!(
        matches!(&err, TrainRunError::DemonstratorTask { path, .. } if *path == grasp),
        "{err}"
    );
    assert!(err.to_string().contains("Grasp"), "{err}");
    let mut same = settings;
    same.task = TaskArg::Grasp;
    same.start.demonstrator_policy = Some(grasp);
    assert!(TrainPlan::new(same).is_ok());
    assert!(!dir.join("run").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A random actor of `inputs` inputs exported with a random normalisation.
fn export_inputs(inputs: usize, seed: u64) -> (Trainer, Vec<u8>) {
    let mut rng = Rng::seed_from_u64(seed);
    let t = random_actor_of(inputs, &mut rng);
    let mean: Vec<f32> = (0..inputs).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let inv_std: Vec<f32> = (0..inputs).map(|_| rng.uniform(0.5, 3.0)).collect();
    let info = ExportInfo {
        task: Task::Grasp,
        seed: 0,
        transitions: 0,
        success_rate: None,
        eval_episodes: 0,
    };
    let (net, p) = t.actor();
    let norm = ObsNormalisation {
        mean: &mean,
        inv_std: &inv_std,
    };
    let file = export_actor_with(net, p, Some(norm), &info, Precision::F32).unwrap();
    (t, file)
}

/// `features = true` (`--features`): a file that takes the task features starts a run that takes
/// them and no other; the exporter lists them when the actor is as wide as observation + features.
#[test]
fn a_file_with_the_task_features_starts_only_a_run_with_them() {
    use dex_runtime::features::{FEATURE_FIELDS, INPUT_MAX};
    let (featured, file) = export_inputs(INPUT_MAX, 4);
    let aligned = dex_runtime::aligned::aligned_copy(&file);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes()).unwrap();
    assert_eq!(view.body().obs_dim(), INPUT_MAX);
    let last = view.body().observation.iter().last().unwrap().name;
    assert_eq!(last, FEATURE_FIELDS[FEATURE_FIELDS.len() - 1].name);
    // Into an actor of the same width: accepted. Into the plain one: the features are named.
    assert!(actor_params_from_policy(&file, Task::Grasp, featured.actor().0).is_ok());
    let plain = Trainer::new(config(&[16, 16]), OBS_DIM, ACT_DIM).unwrap();
    let e = actor_params_from_policy(&file, Task::Grasp, plain.actor().0).unwrap_err();
    assert!(matches!(e, ImportError::Features { file: true }), "{e}");
    let (_, plain_file) = export_inputs(OBS_DIM, 5);
    let e = actor_params_from_policy(&plain_file, Task::Grasp, featured.actor().0).unwrap_err();
    assert!(matches!(e, ImportError::Features { file: false }), "{e}");
    assert!(e.to_string().contains("features = false"), "{e}");
    // Through the run's settings.
    let dir = std::env::temp_dir().join(format!("dex-init-features-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("featured.dxpl");
    std::fs::write(&path, &file).unwrap();
    let settings = TrainSettings {
        task: TaskArg::Grasp,
        out: dir.join("run"),
        init_policy: Some(path),
        features: true,
        run: config(&[16, 16]),
        ..TrainSettings::default()
    };
    assert_eq!(settings.input_dim(), INPUT_MAX);
    assert!(TrainPlan::new(settings.clone()).is_ok());
    let off = TrainSettings {
        features: false,
        ..settings
    };
    assert!(matches!(
        TrainPlan::new(off).err(),
        Some(TrainRunError::InitPolicy {
            source: ImportError::Features { file: true },
            ..
        })
    ));
    let _ = std::fs::remove_dir_all(&dir);
}

//! An IBRL run's pair as a teacher (`trainer train --ibrl`, then `trainer compare --pair` and
//! `trainer imitate --teacher-pair`): the pair labels each state with whichever of the run's
//! actor and its proposal the run's critic rates higher; runs that are not IBRL runs, missing
//! folders and pairs of another task are refused before any work (needs MuJoCo).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use dex_trainer::cell::policy_demo::{DemoSource, PolicyDemonstration};
use dex_trainer::cell::proposal_pair::{ProposalPair, ProposalPairError};
use dex_trainer::cell::run_folder::RunFolderError;
use dex_trainer::env::Task;
use dex_trainer::files::demos::{Keep, RecordMode, RecordSettings, record_with};
use dex_trainer::learn::Trainer;
use dex_trainer::pipeline::imitation::{ImitationConfig, run_imitation};
use dex_trainer::pipeline::train_settings::TaskArg;

mod common;
use common::{REACH_FIXTURE, fresh_path, reach_fixture_run, scene, text, trainer};

/// A short Reach fine-tune of the fixture, with or without the proposal, trained to the end;
/// its seed folder.
fn reach_run(name: &str, ibrl: bool) -> std::path::PathBuf {
    reach_fixture_run(&fresh_path("pair", name), 400, |s| {
        s.run.updates_per_step = 4;
        s.run.ibrl = ibrl;
    })
}

#[test]
fn a_pair_labels_with_the_better_rated_action_and_bad_pairs_are_refused() {
    let dir = reach_run("ibrl", true);
    let (mut pair, task) = ProposalPair::from_run(&dir).unwrap();
    assert_eq!(task, TaskArg::Reach);

    // The run's own networks, read independently of the pair: the checkpoint's actor and
    // critic, the fixture imported as the proposal.
    let t = Trainer::load(&dir.join("checkpoint.bin")).unwrap();
    let nets = t.networks();
    let fixture = std::fs::read(REACH_FIXTURE).unwrap();
    let proposal = dex_trainer::files::policy_import::actor_params_from_policy(
        &fixture,
        Task::Reach,
        &nets.actor,
    )
    .unwrap();
    let q = |x: &[f32], a: &[f32]| {
        let mut row = x.to_vec();
        row.extend_from_slice(a);
        nets.critic
            .forward(t.critic().1, &row, 1, &mut nets.critic.scratch(1))
            .unwrap()[0]
    };

    // The fixture drives two episodes (DAgger, no noise); the pair labels every state.
    let lead = PolicyDemonstration::from_file_bytes(&fixture).unwrap();
    let settings = RecordSettings {
        episodes: 2,
        mode: RecordMode::Dagger,
        keep: Keep::All,
        ..RecordSettings::new(Task::Reach)
    };
    let set = record_with(
        scene(),
        Some(&lead),
        &DemoSource::Pair(Box::new(pair.clone())),
        &settings,
        &|| {},
    )
    .unwrap();
    assert!(
        set.header.source.starts_with("IBRL pair"),
        "{}",
        set.header.source
    );
    let (mut by_actor, mut by_proposal) = (0, 0);
    for row in &set.rows {
        let x = &row.obs[..nets.obs_dim];
        let mut a = vec![0.0f32; nets.act_dim];
        t.act(x, &mut a).unwrap();
        let p = nets
            .actor
            .forward(&proposal, x, 1, &mut nets.actor.scratch(1))
            .unwrap()
            .to_vec();
        let want = if q(x, &p) > q(x, &a) {
            by_proposal += 1;
            p
        } else {
            by_actor += 1;
            a
        };
        assert_eq!(row.label.to_vec(), want);
        // The pair's own answer is the same, and counted.
        assert_eq!(pair.act_on(x).unwrap().0.to_vec(), want);
    }
    assert_eq!(by_actor + by_proposal, set.rows.len());
    // Both members label some states: the test sees the choice, not one member.
    assert!(
        by_actor > 0 && by_proposal > 0,
        "{by_actor} / {by_proposal}"
    );
    let share = pair.proposal_share();
    assert!((share - by_proposal as f64 / set.rows.len() as f64).abs() < 1e-12);

    // `trainer compare --pair` measures it beside the files.
    let o = trainer(&[
        "compare",
        REACH_FIXTURE,
        "--pair",
        dir.to_str().unwrap(),
        "--episodes",
        "3",
        "--threads",
        "1",
    ]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(out.contains("IBRL pair of"), "{out}");

    // A run without the proposal is not a pair; a missing folder is an error that names it.
    let plain = reach_run("plain", false);
    assert!(matches!(
        ProposalPair::from_run(&plain),
        Err(ProposalPairError::NotAPair { .. })
    ));
    assert!(matches!(
        ProposalPair::from_run(&plain.join("nothing")),
        Err(ProposalPairError::Run(RunFolderError::Io { .. }))
    ));

    // Distilling a Reach pair into a Grasp network, or with two teachers, is refused before
    // the run's folder is made.
    for (cfg, why) in [
        (
            ImitationConfig {
                task: Task::Grasp,
                teacher_pair: Some(dir.clone()),
                ..ImitationConfig::default()
            },
            "Reach run",
        ),
        (
            ImitationConfig {
                task: Task::Reach,
                teacher_pair: Some(dir.clone()),
                teacher_policies: vec![REACH_FIXTURE.into()],
                ..ImitationConfig::default()
            },
            "one teacher",
        ),
    ] {
        let out = fresh_path("pair", "distil");
        let err = run_imitation(scene(), &cfg, &out, &mut |_| {}).unwrap_err();
        assert!(err.to_string().contains(why), "{err}");
        assert!(!out.exists());
    }
    let _ = std::fs::remove_dir_all(dir.parent().unwrap());
    let _ = std::fs::remove_dir_all(plain.parent().unwrap());
}

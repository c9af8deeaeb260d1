//! The committed DBC and CAN vectors are exactly what the codec generates now.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

#[test]
fn committed_dbc_matches_the_codec() {
    let committed = include_str!("../../can/jaco.dbc");
    let fresh = dex_runtime::dbc::generate(dex_runtime::ControllerConfig::default().node_id);
    assert_eq!(
        committed, fresh,
        "can/jaco.dbc is stale: run `cargo run -p dex-runtime --example make_dbc`"
    );
}

#[test]
fn committed_fd_dbc_matches_the_codec() {
    let committed = include_str!("../../can/jaco_fd.dbc");
    let fresh = dex_runtime::dbc::generate_fd(dex_runtime::ControllerConfig::default().node_id);
    assert_eq!(
        committed, fresh,
        "can/jaco_fd.dbc is stale: run `cargo run -p dex-runtime --example make_dbc`"
    );
}

#[test]
fn committed_vectors_match_the_codec() {
    let committed = include_str!("../../tests/can/vectors.json");
    assert_eq!(
        committed,
        dex_runtime::testkit::can_vectors_json(),
        "tests/can/vectors.json is stale: run `cargo run -p dex-runtime --example make_can_vectors`"
    );
    let parsed: serde_json::Value = serde_json::from_str(committed).unwrap();
    assert!(parsed.as_array().unwrap().len() >= 30 + 3 + 3 + 3);
}

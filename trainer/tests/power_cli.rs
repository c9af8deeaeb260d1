//! `trainer power`: the size of the next paired test, read off plain and pooled comparison
//! records (the repository's own records of sessions 33 and 41); bad records and levels are
//! refused with a clear error.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;
use common::{fresh_path, text, trainer};

use dex_trainer::env::paired_power::{DiscordantRates, power, starts_needed};

const DOCS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/results/comparisons");

#[test]
fn power_plans_every_pair_of_plain_and_pooled_records() {
    // Confirmation 35 (pooled, 10,000 starts): the clone leads 26 to 17. Confirmation 22 (plain,
    // 20,000 starts): the fine-tune leads 75 to 48.
    let pooled = format!("{DOCS}/session41/confirm35.json");
    let plain = format!("{DOCS}/session33/confirm22.json");
    let o = trainer(&["power", &pooled, &plain]);
    assert!(o.status.success(), "{}", text(&o));
    let out = text(&o);
    for (n, lead, other) in [(10_000u64, 26.0, 17.0), (20_000, 75.0, 48.0)] {
        let rates = DiscordantRates::new(lead / n as f64, other / n as f64).unwrap();
        let needed = starts_needed(rates, 0.01, 0.8, 10_000_000)
            .unwrap()
            .unwrap();
        assert!(needed > n, "{needed}");
        assert!(out.contains(&format!("starts needed: {needed} ")), "{out}");
        let at_size = power(n, rates, 0.01).unwrap();
        assert!(
            out.contains(&format!("a test of {n} starts has power {at_size:.2}")),
            "{out}"
        );
    }
    assert!(out.contains("policies/stack.dxpl leads"), "{out}");
    // A looser level needs fewer starts.
    let o = trainer(&["power", &plain, "--alpha", "0.05"]);
    assert!(o.status.success(), "{}", text(&o));
    let rates = DiscordantRates::new(75.0 / 20_000.0, 48.0 / 20_000.0).unwrap();
    let looser = starts_needed(rates, 0.05, 0.8, 10_000_000)
        .unwrap()
        .unwrap();
    assert!(
        looser
            < starts_needed(rates, 0.01, 0.8, 10_000_000)
                .unwrap()
                .unwrap()
    );
    assert!(
        text(&o).contains(&format!("starts needed: {looser} ")),
        "{}",
        text(&o)
    );
}

#[test]
fn power_refuses_bad_levels_and_records() {
    let plain = format!("{DOCS}/session33/confirm22.json");
    for (flag, value, why) in [
        ("--alpha", "1", "significance level"),
        ("--alpha", "0", "significance level"),
        ("--power", "1.5", "power must be"),
    ] {
        let o = trainer(&["power", &plain, flag, value]);
        assert!(!o.status.success(), "{flag} {value}");
        assert!(text(&o).contains(why), "{flag} {value}: {}", text(&o));
    }
    let dir = fresh_path("power", "bad-records");
    std::fs::create_dir_all(&dir).unwrap();
    // Not a record: named in the error.
    let not = dir.join("not-a-record.json");
    std::fs::write(&not, "{\"successes\": 3}").unwrap();
    let o = trainer(&["power", not.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(text(&o).contains("not-a-record.json"), "{}", text(&o));
    // Discordant starts the record's starts cannot hold: refused before anything is printed.
    let mut r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&plain).unwrap()).unwrap();
    r["pairs"][0]["paired"]["only_a"] = serde_json::json!(30_000);
    let bad = dir.join("inconsistent.json");
    std::fs::write(&bad, r.to_string()).unwrap();
    let o = trainer(&["power", &plain, bad.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(text(&o).contains("discordant starts of"), "{}", text(&o));
    assert!(!text(&o).contains("starts needed"), "{}", text(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

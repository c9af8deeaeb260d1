//! Reading a settings file over the defaults.

use std::path::Path;

use super::{SettingsError, TrainSettings, UnknownSetting};

/// Overlays `overlay` onto `base` key by key (tables merge, other values replace). A table none of
/// whose keys the base has replaces it whole: that is how an enum switches variant
/// (`[run.ddpg.target.polyak]` over the default `copy`).
fn merge(base: &mut toml::Value, overlay: toml::Value) {
    match (base, overlay) {
        (toml::Value::Table(b), toml::Value::Table(o))
            if !b.is_empty() && o.keys().all(|k| !b.contains_key(k)) =>
        {
            *b = o;
        }
        (toml::Value::Table(b), toml::Value::Table(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

/// Every key of `overlay` must exist in `parsed` (the settings read back): catches typos that serde
/// would silently skip.
fn check_keys(
    overlay: &toml::Value,
    parsed: &toml::Value,
    path: &str,
) -> Result<(), UnknownSetting> {
    if let (toml::Value::Table(o), toml::Value::Table(p)) = (overlay, parsed) {
        for (k, v) in o {
            let here = if path.is_empty() {
                k.clone()
            } else {
                format!("{path}.{k}")
            };
            match p.get(k) {
                Some(pv) => check_keys(v, pv, &here)?,
                None => return Err(UnknownSetting { key: here }),
            }
        }
    }
    Ok(())
}

/// Defaults overlaid with the TOML file at `path`.
pub fn load(path: Option<&Path>) -> Result<TrainSettings, SettingsError> {
    let Some(path) = path else {
        return Ok(TrainSettings::default());
    };
    let text = std::fs::read_to_string(path).map_err(|source| SettingsError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let overlay: toml::Value = toml::from_str(&text).map_err(|source| SettingsError::Toml {
        path: path.to_path_buf(),
        source: Box::new(source),
    })?;
    let mut base = toml::Value::try_from(TrainSettings::default())?;
    merge(&mut base, overlay.clone());
    let settings: TrainSettings = base.try_into().map_err(|source| SettingsError::BadValue {
        path: path.to_path_buf(),
        source: Box::new(source),
    })?;
    check_keys(&overlay, &toml::Value::try_from(&settings)?, "").map_err(|source| {
        SettingsError::UnknownKey {
            path: path.to_path_buf(),
            source,
        }
    })?;
    Ok(settings)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::StartScheme;
    use crate::learn::TargetUpdate;
    use crate::pipeline::train_settings::TaskArg;

    /// An error and its causes, as `anyhow` prints them with `{:#}`.
    fn chain(e: &dyn std::error::Error) -> String {
        let mut s = e.to_string();
        let mut cause = e.source();
        while let Some(c) = cause {
            s.push_str(&format!(": {c}"));
            cause = c.source();
        }
        s
    }

    #[test]
    fn file_values_override_defaults_and_typos_are_errors() {
        let dir = std::env::temp_dir().join(format!("dex-cfg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("good.toml");
        std::fs::write(
            &good,
            "task = \"grasp\"\ntransitions = 5\n[run]\nupdates_per_step = 40\n[run.ddpg]\nbatch_size = 256\n",
        )
        .unwrap();
        let s = load(Some(&good)).unwrap();
        assert_eq!(s.task, TaskArg::Grasp);
        assert_eq!(s.transitions, 5);
        assert_eq!(s.run.updates_per_step, 40);
        assert_eq!(s.run.ddpg.batch_size, 256);
        assert_eq!(s.run.ddpg.gamma, TrainSettings::default().run.ddpg.gamma);
        let polyak = dir.join("polyak.toml");
        std::fs::write(&polyak, "[run.ddpg.target.polyak]\ntau = 0.01\n").unwrap();
        let s = load(Some(&polyak)).unwrap();
        assert_eq!(s.run.ddpg.target, TargetUpdate::Polyak { tau: 0.01 });
        let copy = dir.join("copy.toml");
        std::fs::write(&copy, "[run.ddpg.target.copy]\nevery = 50\n").unwrap();
        let s = load(Some(&copy)).unwrap();
        assert_eq!(s.run.ddpg.target, TargetUpdate::Copy { every: 50 });
        let bad = dir.join("bad.toml");
        std::fs::write(&bad, "[run]\nupdates_per_stepp = 40\n").unwrap();
        let e = load(Some(&bad)).unwrap_err();
        assert!(chain(&e).contains("updates_per_stepp"), "{}", chain(&e));
        std::fs::write(&bad, "task = \"juggle\"\n").unwrap();
        assert!(load(Some(&bad)).is_err());
        let demo = dir.join("demo.toml");
        std::fs::write(&demo, "[start]\nscheme = \"along-demonstrations\"\n").unwrap();
        let s = load(Some(&demo)).unwrap();
        assert_eq!(
            s.start.scheme(),
            StartScheme::AlongDemonstrations {
                train_episode_steps: 50,
                demonstrations: 0,
            }
        );
        std::fs::write(
            &bad,
            "[start]\nscheme = \"mixture\"\nin_hand_probability = 1.5\n",
        )
        .unwrap();
        let e = load(Some(&bad)).unwrap().validate().unwrap_err();
        assert!(chain(&e).contains("in-hand probability"), "{}", chain(&e));
        std::fs::write(&bad, "[start]\nscheme = \"teleport\"\n").unwrap();
        assert!(load(Some(&bad)).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn every_setting_at_its_default_value_loads() {
        // A key written at its default (here the guard off) is a known key, not an unknown one.
        let dir = std::env::temp_dir().join(format!("dex-guard-zero-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("s.toml");
        std::fs::write(&path, "guard_episodes = 0\n").unwrap();
        assert_eq!(load(Some(&path)).unwrap().guard_episodes, 0);
        std::fs::write(&path, "guard_episodes = 500\n").unwrap();
        assert_eq!(load(Some(&path)).unwrap().guard_episodes, 500);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn unknown_keys_are_named_by_their_path() {
        let parsed = toml::Value::try_from(TrainSettings::default()).unwrap();
        let overlay: toml::Value = toml::from_str("[run]\nupdates_per_stepp = 40\n").unwrap();
        let e = check_keys(&overlay, &parsed, "").unwrap_err();
        assert_eq!(e.to_string(), "unknown setting `run.updates_per_stepp`");
        let known: toml::Value = toml::from_str("[run]\nupdates_per_step = 40\n").unwrap();
        assert!(check_keys(&known, &parsed, "").is_ok());
    }
}

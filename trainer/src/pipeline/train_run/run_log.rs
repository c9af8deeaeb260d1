//! The evaluation log of a seed (`eval.jsonl`) kept in step with its checkpoint.

use super::*;

/// Keeps the records of `eval.jsonl` up to `transitions` (those a checkpoint holds), rewriting the
/// file atomically when it has later ones.
pub(super) fn truncate_log(path: &Path, transitions: u64) -> Result<(), TrainRunError> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(());
    };
    let keep: Vec<&str> = text
        .lines()
        .filter(|l| {
            serde_json::from_str::<serde_json::Value>(l)
                .ok()
                .and_then(|v| v["transitions"].as_u64())
                .is_some_and(|t| t <= transitions)
        })
        .collect();
    if keep.len() != text.lines().count() {
        let mut out = keep.join("\n");
        if !out.is_empty() {
            out.push('\n');
        }
        write_file(path, out.as_bytes())?;
    }
    Ok(())
}

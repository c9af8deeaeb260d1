//! The action trace's line format (`std` only): what `trainer eval --actions` and `hil-sim
//! plant --actions` write, one line per control step, so two traces are equal exactly when every
//! command is bit-identical.

/// One line of an action trace, `episode step a0 ... a8\n`, each value in Rust's shortest
/// round-trip decimal: the format `trainer eval --actions` and `hil-sim plant --actions` write, so
/// two traces are equal exactly when every command is bit-identical.
pub fn action_line(episode: u64, step: usize, action: &[f32]) -> std::string::String {
    use core::fmt::Write;
    let mut line = std::format!("{episode} {step}");
    for a in action {
        // Writing into a String cannot fail.
        let _ = write!(line, " {a:?}");
    }
    line.push('\n');
    line
}

//! Control commands: fault injection, virtual time, reports.

#[cfg(doc)]
use super::Bus;

/// What a fault rule does to a matching frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// The frame disappears.
    Drop,
    /// One bit of the last data byte is flipped (an E2E CRC error for protected frames).
    Corrupt,
    /// The frame is put on the bus this many microseconds of bus time later.
    Delay(u64),
}

/// One injected fault: applies to frames with `id` (all frames if `None`), `remaining` times
/// (until cleared if `None`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultRule {
    /// The effect.
    pub kind: FaultKind,
    /// Raw identifier matched, or every frame.
    pub id: Option<u32>,
    /// Frames left to affect.
    pub remaining: Option<u64>,
}

/// A parsed control command (`< fault ... >`, `< time US >`, `< stats >`, `< diag >`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ControlCommand {
    /// Add a fault rule.
    Fault(FaultRule),
    /// Bus-off for this many microseconds of bus time (0: until [`ControlCommand::Clear`]).
    BusOff(u64),
    /// Remove every fault rule and end bus-off.
    Clear,
    /// Set virtual bus time (lockstep).
    Time(u64),
    /// The frames this client sends next are offered to the wire at this bus time (lockstep;
    /// never earlier than the bus time): a node's answer after its compute. Not answered.
    TxTime(u64),
    /// Report the bus time: the clock, or the end of the last frame on the wire if later.
    Now,
    /// Report the bus counters.
    Stats,
    /// Report the status line of the in-process controller node.
    Diag,
    /// Ask the process that owns the bus to exit (see [`Bus::quit_requested`]).
    Quit,
}

/// Parses control words, e.g. `fault drop 205 1`, `fault delay * 30000 0`, `fault busoff 300`
/// (`fault busoff 0`: off until `fault clear`).
pub fn parse_control(words: &[String]) -> Result<ControlCommand, String> {
    let w: Vec<&str> = words.iter().map(String::as_str).collect();
    let id = |s: &str| -> Result<Option<u32>, String> {
        if s == "*" {
            Ok(None)
        } else {
            u32::from_str_radix(s.trim_start_matches("0x"), 16)
                .map(Some)
                .map_err(|_| format!("bad id {s}"))
        }
    };
    let num = |s: &str| -> Result<u64, String> { s.parse().map_err(|_| format!("bad number {s}")) };
    let count = |s: &str| -> Result<Option<u64>, String> {
        num(s).map(|n| if n == 0 { None } else { Some(n) })
    };
    match w.as_slice() {
        ["fault", "drop", i, n] => Ok(ControlCommand::Fault(FaultRule {
            kind: FaultKind::Drop,
            id: id(i)?,
            remaining: count(n)?,
        })),
        ["fault", "corrupt", i, n] => Ok(ControlCommand::Fault(FaultRule {
            kind: FaultKind::Corrupt,
            id: id(i)?,
            remaining: count(n)?,
        })),
        ["fault", "delay", i, us, n] => Ok(ControlCommand::Fault(FaultRule {
            kind: FaultKind::Delay(num(us)?),
            id: id(i)?,
            remaining: count(n)?,
        })),
        ["fault", "busoff", ms] => Ok(ControlCommand::BusOff(num(ms)?.saturating_mul(1000))),
        ["fault", "clear"] => Ok(ControlCommand::Clear),
        ["time", us] => Ok(ControlCommand::Time(num(us)?)),
        ["txtime", us] => Ok(ControlCommand::TxTime(num(us)?)),
        ["now"] => Ok(ControlCommand::Now),
        ["stats"] => Ok(ControlCommand::Stats),
        ["diag"] => Ok(ControlCommand::Diag),
        ["quit"] => Ok(ControlCommand::Quit),
        _ => Err(format!("unknown control command: {}", w.join(" "))),
    }
}

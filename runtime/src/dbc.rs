//! Generates the cell's DBC description (`can/jaco.dbc`) from [`crate::interface`] and
//! [`crate::can::messages`], so the file can never drift from the codec (`std` only). A DBC
//! names fixed identifiers: the committed file is that of the default node 0x10; another node's
//! frames have the same layouts on the identifiers [`crate::can::messages::rpdo_cob_id`] and
//! [`crate::can::messages::tpdo_cob_id`] give (or generate its own with [`generate`]).
//!
//! The CAN FD layout ([`crate::can::fd_messages`]) has its own file from the same definitions,
//! `can/jaco_fd.dbc` ([`generate_fd`]): the two 48-byte observation frames and the 20-byte action
//! frame marked as FD frames with bit-rate switching (the `VFrameFormat` attribute
//! `StandardCAN_FD`, `CANFD_BRS` 1, `BusType` "CAN FD", as cantools and Vector tools read them);
//! every other message as in `can/jaco.dbc`.

use std::fmt::Write;
use std::string::String;

use crate::can::fd_messages::{FD_ACTION_LEN, FD_OBS_FRAMES, FD_OBS_LEN, FD_VALUES_PER_OBS_FRAME};
use crate::can::layout::FrameLayout;
use crate::can::messages::{
    ACTION_FRAMES, ACTION_QUANTITY, EMCY_BASE_ID, HEARTBEAT_BASE_ID, NMT_ID, OBS_FRAMES,
    POLICY_INFO_TPDO, SIGNALS_PER_FRAME, STATUS_LEN, STATUS_TPDO, rpdo_cob_id, tpdo_cob_id,
};
use crate::controller::FaultCode;
use crate::interface::{ACTION_JOINTS, OBSERVATION_FIELDS, Quantity};

/// Every fault code, in code order (the DBC's value tables).
const FAULTS: [FaultCode; 10] = [
    FaultCode::None,
    FaultCode::ObservationTimeout,
    FaultCode::ObservationNonFinite,
    FaultCode::ObservationOutOfRange,
    FaultCode::ActionNonFinite,
    FaultCode::NoPolicy,
    FaultCode::BusOff,
    FaultCode::PolicyRolledBack,
    FaultCode::EnvelopeSustained,
    FaultCode::EnvelopeConfig,
];

/// Status TPDO byte 4 (object 0x2001), bit by bit from bit 0: `envelope::status`.
pub const ENVELOPE_BITS: [&str; 6] = [
    "envelope_enabled",
    "envelope_sustained",
    "envelope_joint_limit",
    "envelope_table",
    "envelope_workspace",
    "envelope_acceleration",
];

/// The DBC name of a fault code and of its emergency error code.
fn fault_names(fault: FaultCode) -> (&'static str, &'static str) {
    match fault {
        FaultCode::None => ("none", "error_reset"),
        FaultCode::ObservationTimeout => ("observation_timeout", "observation_timeout"),
        FaultCode::ObservationNonFinite => ("observation_non_finite", "observation_non_finite"),
        FaultCode::ObservationOutOfRange => {
            ("observation_out_of_range", "observation_out_of_range")
        }
        FaultCode::ActionNonFinite => ("action_non_finite", "action_non_finite"),
        FaultCode::NoPolicy => ("no_policy", "no_policy"),
        FaultCode::BusOff => ("bus_off", "recovered_from_bus_off"),
        FaultCode::PolicyRolledBack => ("policy_rolled_back", "policy_rolled_back"),
        FaultCode::EnvelopeSustained => ("envelope_sustained", "envelope_sustained"),
        FaultCode::EnvelopeConfig => ("envelope_config", "envelope_config"),
    }
}

/// `VAL_ id signal v "name" ... ;` for the fault codes, or (`emcy`) their error codes by value.
fn fault_values(out: &mut String, id: u16, signal: &str, emcy: bool) {
    let mut rows: std::vec::Vec<(u16, &str)> = FAULTS
        .iter()
        .map(|&f| {
            let (name, emcy_name) = fault_names(f);
            if emcy {
                (f.emcy_code(), emcy_name)
            } else {
                (u16::from(f.code()), name)
            }
        })
        .collect();
    rows.sort_unstable();
    let _ = write!(out, "VAL_ {id} {signal}");
    for (value, name) in rows {
        let _ = write!(out, " {value} \"{name}\"");
    }
    out.push_str(" ;\n");
}

/// Name of observation value `index` in the DBC (`<field>_<n>`).
pub fn observation_signal_name(index: usize) -> Option<String> {
    let mut start = 0;
    for f in OBSERVATION_FIELDS {
        if index < start + f.size {
            return Some(std::format!("{}_{}", f.name, index - start));
        }
        start += f.size;
    }
    None
}

/// Name of observation frame `k` (`OBS_00`...).
pub fn observation_message_name(k: usize) -> String {
    std::format!("OBS_{k:02}")
}

/// Name of action frame `k` (`ACTION_0`...).
pub fn action_message_name(k: usize) -> String {
    std::format!("ACTION_{k}")
}

fn e2e_header(out: &mut String, receiver: &str, nibble: Option<&str>) {
    let _ = writeln!(out, " SG_ crc : 0|8@1+ (1,0) [0|255] \"\" {receiver}");
    let _ = writeln!(
        out,
        " SG_ alive_counter : 8|4@1+ (1,0) [0|14] \"\" {receiver}"
    );
    if let Some(name) = nibble {
        let _ = writeln!(out, " SG_ {name} : 12|4@1+ (1,0) [0|15] \"\" {receiver}");
    }
}

/// The physical value per bit as the DBC states it (the decimal of [`scale_text`]).
pub fn dbc_scale(lsb: f32) -> f64 {
    scale_text(lsb).parse().unwrap_or(f64::from(lsb))
}

/// Scale as text: exact for powers of two, else the shortest decimal that reads back as the f32.
fn scale_text(lsb: f32) -> String {
    let exact = f64::from(lsb);
    if exact.log2().fract() == 0.0 {
        std::format!("{exact}")
    } else {
        std::format!("{lsb}")
    }
}

fn signal(out: &mut String, name: &str, slot: usize, q: Quantity, limit: f32, receiver: &str) {
    let _ = writeln!(
        out,
        " SG_ {name} : {}|16@1- ({},0) [{}|{}] \"{}\" {receiver}",
        16 + 16 * slot,
        scale_text(q.lsb()),
        -limit,
        limit,
        q.unit()
    );
}

/// The DBC text for a controller with CANopen node id `node` (the classic layout).
pub fn generate(node: u8) -> String {
    generate_layout(node, FrameLayout::Classic)
}

/// The DBC text of the CAN FD layout for a controller with CANopen node id `node`.
pub fn generate_fd(node: u8) -> String {
    generate_layout(node, FrameLayout::Fd)
}

/// Name of FD observation frame `k` (`OBS_FD_0`, `OBS_FD_1`).
pub fn fd_observation_message_name(k: usize) -> String {
    std::format!("OBS_FD_{k}")
}

/// Name of the FD action frame.
pub const FD_ACTION_MESSAGE: &str = "ACTION_FD";

/// The FD layout's observation and action messages.
fn fd_messages(out: &mut String, node: u8) {
    let _ = writeln!(
        out,
        "BO_ {} {FD_ACTION_MESSAGE}: {FD_ACTION_LEN} CONTROLLER",
        tpdo_cob_id(node, 0)
    );
    e2e_header(out, "PLANT", Some("sample_counter"));
    for (slot, j) in ACTION_JOINTS.iter().enumerate() {
        signal(out, j.name, slot, ACTION_QUANTITY, j.max, "PLANT");
    }
    out.push('\n');
    for k in 0..FD_OBS_FRAMES {
        let _ = writeln!(
            out,
            "BO_ {} {}: {FD_OBS_LEN} PLANT",
            rpdo_cob_id(node, k),
            fd_observation_message_name(k)
        );
        e2e_header(out, "CONTROLLER", Some("sample_counter"));
        for slot in 0..FD_VALUES_PER_OBS_FRAME {
            let index = k * FD_VALUES_PER_OBS_FRAME + slot;
            if let (Some(name), Some(q)) = (
                observation_signal_name(index),
                crate::interface::quantity_of(index),
            ) {
                signal(out, &name, slot, q, q.limit(), "CONTROLLER");
            }
        }
        out.push('\n');
    }
}

/// The attributes that mark the FD layout's frames as CAN FD frames with bit-rate switching.
fn fd_attributes(out: &mut String, node: u8) {
    out.push_str("BA_DEF_ \"BusType\" STRING ;\n");
    out.push_str(
        "BA_DEF_ BO_ \"VFrameFormat\" ENUM \"StandardCAN\",\"ExtendedCAN\",\"reserved\",\"J1939PG\",\
         \"reserved\",\"reserved\",\"reserved\",\"reserved\",\"reserved\",\"reserved\",\"reserved\",\
         \"reserved\",\"reserved\",\"reserved\",\"StandardCAN_FD\",\"ExtendedCAN_FD\";\n",
    );
    out.push_str("BA_DEF_ BO_ \"CANFD_BRS\" ENUM \"0\",\"1\";\n");
    out.push_str("BA_DEF_DEF_ \"BusType\" \"CAN\";\n");
    out.push_str("BA_DEF_DEF_ \"VFrameFormat\" \"StandardCAN\";\n");
    out.push_str("BA_DEF_DEF_ \"CANFD_BRS\" \"1\";\n");
    out.push_str("BA_ \"BusType\" \"CAN FD\";\n");
    let ids = core::iter::once(tpdo_cob_id(node, 0))
        .chain((0..FD_OBS_FRAMES).map(|k| rpdo_cob_id(node, k)));
    for id in ids {
        // 14: StandardCAN_FD.
        let _ = writeln!(out, "BA_ \"VFrameFormat\" BO_ {id} 14;");
        let _ = writeln!(out, "BA_ \"CANFD_BRS\" BO_ {id} 1;");
    }
}

/// The DBC text for node `node` in `layout`.
fn generate_layout(node: u8, layout: FrameLayout) -> String {
    let fd = layout == FrameLayout::Fd;
    let mut out = String::new();
    out.push_str("VERSION \"dexterous-stack jaco cell 1\"\n\nNS_ :\n\tCM_\n\tBA_DEF_\n\tBA_\n\tVAL_\n\nBS_:\n\n");
    out.push_str("BU_: MASTER PLANT CONTROLLER\n\n");
    let _ = writeln!(out, "BO_ {NMT_ID} NMT: 2 MASTER");
    out.push_str(" SG_ command : 0|8@1+ (1,0) [0|255] \"\" CONTROLLER\n");
    out.push_str(" SG_ node_id : 8|8@1+ (1,0) [0|127] \"\" CONTROLLER\n\n");

    let emcy = EMCY_BASE_ID + u16::from(node);
    // CiA 301: error code, error register, then 5 manufacturer-specific bytes, the E2E
    // protection at the end (E2eLayout::Tail).
    let _ = writeln!(out, "BO_ {emcy} EMCY: 8 CONTROLLER");
    out.push_str(" SG_ error_code : 0|16@1+ (1,0) [0|65535] \"\" MASTER\n");
    out.push_str(" SG_ error_register : 16|8@1+ (1,0) [0|255] \"\" MASTER\n");
    out.push_str(" SG_ fault_code : 24|8@1+ (1,0) [0|255] \"\" MASTER\n");
    out.push_str(" SG_ state : 32|8@1+ (1,0) [0|4] \"\" MASTER\n");
    out.push_str(" SG_ alive_counter : 48|4@1+ (1,0) [0|14] \"\" MASTER\n");
    out.push_str(" SG_ crc : 56|8@1+ (1,0) [0|255] \"\" MASTER\n\n");

    for k in (0..ACTION_FRAMES).filter(|_| !fd) {
        let _ = writeln!(
            out,
            "BO_ {} {}: 8 CONTROLLER",
            tpdo_cob_id(node, k),
            action_message_name(k)
        );
        e2e_header(&mut out, "PLANT", Some("sample_counter"));
        for slot in 0..SIGNALS_PER_FRAME {
            if let Some(j) = ACTION_JOINTS.get(k * SIGNALS_PER_FRAME + slot) {
                signal(&mut out, j.name, slot, ACTION_QUANTITY, j.max, "PLANT");
            }
        }
        out.push('\n');
    }

    let status = tpdo_cob_id(node, STATUS_TPDO);
    let _ = writeln!(out, "BO_ {status} STATUS: {STATUS_LEN} CONTROLLER");
    e2e_header(&mut out, "MASTER", None);
    out.push_str(" SG_ state : 16|8@1+ (1,0) [0|4] \"\" MASTER\n");
    out.push_str(" SG_ fault_code : 24|8@1+ (1,0) [0|255] \"\" MASTER\n");
    // Byte 4: the safety envelope's status bits (runtime/src/envelope.rs, `status`).
    for (bit, name) in ENVELOPE_BITS.iter().enumerate() {
        let _ = writeln!(
            out,
            " SG_ {name} : {}|1@1+ (1,0) [0|1] \"\" MASTER",
            32 + bit
        );
    }
    out.push('\n');

    if fd {
        fd_messages(&mut out, node);
    }
    for k in (0..OBS_FRAMES).filter(|_| !fd) {
        let _ = writeln!(
            out,
            "BO_ {} {}: 8 PLANT",
            rpdo_cob_id(node, k),
            observation_message_name(k)
        );
        e2e_header(&mut out, "CONTROLLER", Some("sample_counter"));
        for slot in 0..SIGNALS_PER_FRAME {
            let index = k * SIGNALS_PER_FRAME + slot;
            if let (Some(name), Some(q)) = (
                observation_signal_name(index),
                crate::interface::quantity_of(index),
            ) {
                signal(&mut out, &name, slot, q, q.limit(), "CONTROLLER");
            }
        }
        out.push('\n');
    }

    let info = tpdo_cob_id(node, POLICY_INFO_TPDO);
    let _ = writeln!(out, "BO_ {info} POLICY_INFO: 8 CONTROLLER");
    e2e_header(&mut out, "MASTER", None);
    out.push_str(" SG_ layout_hash : 16|32@1+ (1,0) [0|4294967295] \"\" MASTER\n");
    out.push_str(" SG_ format_version : 48|8@1+ (1,0) [0|255] \"\" MASTER\n");
    out.push_str(" SG_ task : 56|8@1+ (1,0) [0|255] \"\" MASTER\n\n");

    let heartbeat = HEARTBEAT_BASE_ID + u16::from(node);
    let _ = writeln!(out, "BO_ {heartbeat} HEARTBEAT: 1 CONTROLLER");
    out.push_str(" SG_ nmt_state : 0|8@1+ (1,0) [0|127] \"\" MASTER\n\n");

    let _ = writeln!(
        out,
        "CM_ \"Generated by dex-runtime (runtime/src/dbc.rs) for CANopen node id {node} (0x{node:02X}); \
         do not edit. Another node id n (1..=31) has the same messages on its own identifiers: \
         RPDO k = 0x200 + 0x100*(k % 4) + n + 32*(k / 4) (OBS_k), TPDO k = 0x180 + 0x100*(k % 4) + \
         n + 32*(k / 4) (ACTION_0..2, POLICY_INFO 3, STATUS 4), EMCY 0x80 + n, HEARTBEAT 0x700 + n. \
         E2E: crc = CRC-8/SAE-J1850 over data id (CAN id, LE u16) and every other byte in order; in \
         the PDOs crc is byte 0 and alive_counter the low nibble of byte 1, in EMCY crc is byte 7 and \
         alive_counter the low nibble of byte 6. Raw -32768 in a 16-bit signal means not available.\";"
    );
    if fd {
        let _ = writeln!(
            out,
            "CM_ BO_ {} \"CAN FD layout (runtime/src/can/fd_messages.rs): observation values 0..22 in OBS_FD_0 \
             (RPDO 1), 22..44 in OBS_FD_1 (RPDO 2), 48 bytes each, bytes 46-47 zero; the same E2E header \
             as the classic frames, keyed by the identifier.\";",
            rpdo_cob_id(node, 0)
        );
        fd_attributes(&mut out, node);
    }
    let _ = writeln!(
        out,
        "VAL_ {status} state 0 \"boot\" 1 \"pre_operational\" 2 \"operational\" 3 \"safe_stop\" 4 \"fault\" ;"
    );
    let _ = writeln!(
        out,
        "VAL_ {emcy} state 0 \"boot\" 1 \"pre_operational\" 2 \"operational\" 3 \"safe_stop\" 4 \"fault\" ;"
    );
    let _ = writeln!(
        out,
        "VAL_ {heartbeat} nmt_state 0 \"boot_up\" 4 \"stopped\" 5 \"operational\" 127 \"pre_operational\" ;"
    );
    let _ = writeln!(
        out,
        "VAL_ {NMT_ID} command 1 \"start\" 2 \"stop\" 128 \"enter_pre_operational\" 129 \"reset_node\" 130 \"reset_communication\" ;"
    );
    fault_values(&mut out, emcy, "error_code", true);
    fault_values(&mut out, emcy, "fault_code", false);
    fault_values(&mut out, status, "fault_code", false);
    out
}

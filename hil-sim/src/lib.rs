//! Software-in-the-loop: a virtual CAN bus, the plant and the controller node.
//!
//! Filled in by the software-in-the-loop issue; see `ARCHITECTURE.md`.

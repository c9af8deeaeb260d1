//! `dex-policy`: the compact policy file format.
#![no_std]

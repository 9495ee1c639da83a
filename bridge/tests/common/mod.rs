//! Helpers of the multi-process bridge tests (loopback.rs, tls.rs): the relay helpers of
//! taxel-testkit (`relay`) with this package's own `taxel-bridge` binary.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

pub use taxel_testkit::relay::*;
use taxel_testkit::Proc;

pub const BRIDGE: &str = env!("CARGO_BIN_EXE_taxel-bridge");

fn exe() -> BridgeExe {
    BridgeExe::standalone(BRIDGE)
}

/// A `taxel-bridge` command (outside any TAXEL_PREFIX of the environment), optionally run in a
/// network namespace.
pub fn bridge_cmd(netns: Option<&str>, args: &[String]) -> Command {
    exe().command(netns, args)
}

pub fn spawn(name: &str, netns: Option<&str>, args: &[String]) -> Proc {
    exe().spawn(name, netns, args)
}

/// `taxel-bridge certs --out dir [--host h]...`: a CA and two pairs.
pub fn make_certs(dir: &Path, hosts: &[&str]) -> PathBuf {
    exe().make_certs(dir, hosts)
}

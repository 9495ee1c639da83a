//! taxel-bridge owns `taxel bridge`: relaying chosen iceoryx2 services of one host to another over
//! Zenoh, for observation and logging (a glove on a wearable computer, the logger and monitor on
//! a workstation). It runs iceoryx2's own link (`iceoryx2-link`) with the tunnel backend
//! (`iceoryx2-link-tunnel`) over the Zenoh carrier (`iceoryx2-integrations-zenoh-link-carrier`,
//! vendored in the repository's `vendor/`, as is Zenoh's TLS link with a fix; see their
//! VENDORED.md):
//! services whose names match the `--allow` globs are offered to the peers, services the peers
//! offer are mirrored into the local domain, publish-subscribe samples and events cross in order, and a sample the
//! bridge published itself is never sent back. This crate adds what taxel needs around the
//! link: the configuration (allow globs, Zenoh endpoints, the stream QoS mirrors are created
//! with), a loop that wakes on local notifications and on Zenoh arrivals, and per-stream
//! statistics (loss from `seq` gaps, reordering, age from `t_capture_ns`). Across a network it
//! runs over Zenoh's TLS transport with mutual authentication (`--tls-cert`, `--tls-key`,
//! `--tls-ca`, see `tls`): peers without a certificate of the CA are refused, logged and counted;
//! without TLS it listens on loopback only unless `--insecure-listen`. The control path stays
//! local: the bridge is not for control (docs/bridge.md).

pub mod certs;
pub mod cli;
pub mod config;
pub mod run;
pub mod stats;
pub mod tls;

pub use config::{BridgeConfig, ConfigError};
pub use run::{run, Report};

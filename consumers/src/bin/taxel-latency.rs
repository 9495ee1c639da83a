use clap::Parser;

fn main() -> std::process::ExitCode {
    taxel_consumers::latency::main(taxel_consumers::latency::Args::parse())
}

use clap::Parser;

fn main() -> std::process::ExitCode {
    taxel_bridge::cli::main(taxel_bridge::cli::Args::parse())
}

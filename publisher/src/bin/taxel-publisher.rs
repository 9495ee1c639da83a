use clap::Parser;

fn main() -> std::process::ExitCode {
    taxel_publisher::cli::main(taxel_publisher::cli::Args::parse())
}

use clap::Parser;

fn main() -> std::process::ExitCode {
    taxel_simcheck::cli::main(taxel_simcheck::cli::Args::parse())
}

use clap::Parser;

fn main() -> std::process::ExitCode {
    taxel_consumers::control::main(taxel_consumers::control::Args::parse())
}

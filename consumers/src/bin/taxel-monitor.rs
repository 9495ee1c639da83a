use clap::Parser;

fn main() -> std::process::ExitCode {
    taxel_consumers::monitor::main(taxel_consumers::monitor::Args::parse())
}

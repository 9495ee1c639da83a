use clap::Parser;

fn main() -> std::process::ExitCode {
    taxel_consumers::logger::main(taxel_consumers::logger::Args::parse())
}

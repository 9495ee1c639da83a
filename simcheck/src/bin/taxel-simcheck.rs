use clap::Parser;

fn main() -> std::process::ExitCode {
    taxel_simcheck::memory::keep_freed_memory();
    taxel_simcheck::cli::main(taxel_simcheck::cli::Args::parse())
}

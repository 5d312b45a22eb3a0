use clap::Parser;

use geostride::cli::{BadInput, Cli};

fn main() {
    let cli = Cli::parse();
    if let Err(e) = cli.run() {
        eprintln!("error: {e:#}");
        let code = if e.downcast_ref::<BadInput>().is_some() {
            2
        } else {
            1
        };
        std::process::exit(code);
    }
}

use clap::Parser;

use geostride::cli::{BadInput, Cli};

fn main() {
    // Die quietly on a closed pipe (`geostride ... | head`) instead of panicking on the write.
    #[cfg(unix)]
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
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

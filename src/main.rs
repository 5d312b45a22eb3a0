use clap::Parser;

mod cli;

use cli::{BadInput, Cli};

fn main() {
    // Die quietly on a closed pipe (`geostride ... | head`) instead of panicking on the write.
    #[cfg(unix)]
    // SAFETY: the default action for SIGPIPE, set before any other thread runs.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // OpenCV's decoders refuse larger images than geostride reads (formats whose header
    // geostride does not read itself: `imageheader`).
    if std::env::var_os("OPENCV_IO_MAX_IMAGE_PIXELS").is_none() {
        // SAFETY: no other thread runs yet.
        unsafe {
            std::env::set_var(
                "OPENCV_IO_MAX_IMAGE_PIXELS",
                geostride::imageheader::MAX_IMAGE_PIXELS.to_string(),
            );
        }
    }
    let cli = Cli::parse();
    if let Err(e) = cli.run() {
        // A message quoting a huge input is cut (readers clip what they quote; this is the net).
        eprintln!("error: {}", geostride::io::clip(&format!("{e:#}"), 4000));
        let code = if e.downcast_ref::<BadInput>().is_some() {
            2
        } else {
            1
        };
        std::process::exit(code);
    }
}

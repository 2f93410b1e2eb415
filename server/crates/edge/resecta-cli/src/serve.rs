//! `resecta serve`: the planning server. Prints one JSON line with the bound addresses on stdout
//! once both faces listen; logs go to stderr; Ctrl-C or SIGTERM stops it gracefully.

use std::io::Write;

use resecta_server::{ServeArgs, ServerConfig, ServerError, init_tracing, run, termination_signal};

use crate::error::CliError;

fn cli_error(e: ServerError) -> CliError {
    if e.is_bad_input() {
        CliError::BadInput(e.to_string())
    } else {
        CliError::Failed(e.to_string())
    }
}

pub fn serve(args: &ServeArgs) -> Result<(), CliError> {
    let config = ServerConfig::resolve(args).map_err(cli_error)?;
    init_tracing(config.log_json);
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_name("resecta-server")
        .build()
        .map_err(|e| CliError::Failed(format!("async runtime: {e}")))?;
    runtime
        .block_on(run(config, termination_signal(), |bound| {
            let mut out = std::io::stdout().lock();
            let _ = serde_json::to_writer(&mut out, &bound);
            let _ = writeln!(out);
            let _ = out.flush();
        }))
        .map_err(cli_error)
}

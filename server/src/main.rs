//! `facerecon-server`: see `--help` and the crate documentation.

use clap::Parser;

fn main() -> std::process::ExitCode {
    let config = match facerecon_server::config::Args::parse().resolve() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("error: {e:#}");
            return std::process::ExitCode::from(2);
        }
    };
    let runtime = match tokio::runtime::Builder::new_multi_thread().enable_all().build() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: starting the runtime: {e}");
            return std::process::ExitCode::FAILURE;
        }
    };
    // Inside the runtime: the OTLP exporter's client needs it.
    let telemetry = match runtime
        .block_on(async { facerecon_server::telemetry::init(config.log_format, config.otlp_endpoint.as_deref()) })
    {
        Ok(t) => t,
        Err(e) => {
            eprintln!("error: {e:#}");
            return std::process::ExitCode::from(2);
        }
    };
    let code = match runtime.block_on(run(config)) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e:#}");
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    };
    // The runtime is still alive (its workers drive the exporter's connection).
    telemetry.shutdown();
    code
}

async fn run(config: facerecon_server::Config) -> anyhow::Result<()> {
    use anyhow::Context;
    if let Some(addr) = config.metrics_listen {
        facerecon_server::metrics::install(addr).with_context(|| format!("starting the metrics exporter on {addr}"))?;
    }
    let listener = tokio::net::TcpListener::bind(config.listen)
        .await
        .with_context(|| format!("listening on {}", config.listen))?;
    tracing::info!(listen = %listener.local_addr()?, metrics = ?config.metrics_listen, "facerecon-server starting");
    let load = facerecon_server::default_loader(&config);
    facerecon_server::serve(config, listener, load, shutdown_signal()).await
}

/// SIGTERM (Kubernetes, docker stop) or Ctrl-C.
async fn shutdown_signal() {
    #[cfg(unix)]
    {
        let mut term = match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(s) => s,
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
                return;
            }
        };
        tokio::select! {
            _ = term.recv() => {}
            _ = tokio::signal::ctrl_c() => {}
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}

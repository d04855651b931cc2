//! The worker side of a relayed session: the in-process host's session through channels, or a
//! registered worker's session socket, both as one `Sink`/`Stream` of protocol messages.

use std::pin::Pin;

use futures::{Sink, SinkExt, Stream, StreamExt};
use render_worker::cluster::UrlError;
use render_worker::session::protocol::{WsMessage, serve_connection};
use tokio_tungstenite::tungstenite::Message as TMessage;

use super::{Dispatcher, Placement};

/// Messages towards the worker.
pub type UpSink = Pin<Box<dyn Sink<WsMessage, Error = String> + Send>>;
/// Messages from the worker.
pub type UpStream = Pin<Box<dyn Stream<Item = Result<WsMessage, String>> + Send>>;

/// Why the worker side of a session could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum UpstreamError {
    /// The session is placed in-process but this server has no in-process worker.
    #[error("no in-process worker")]
    NoInProcessWorker,
    /// The in-process host no longer holds the session.
    #[error("the in-process session has ended")]
    SessionEnded,
    /// The worker's URL cannot be turned into its socket's.
    #[error(transparent)]
    Url(#[from] UrlError),
    /// The worker's session socket did not open.
    #[error("{url}: {source}")]
    Connect {
        /// The socket's URL.
        url: String,
        /// The websocket client's error.
        source: tokio_tungstenite::tungstenite::Error,
    },
}

/// Opens the worker side of a session.
pub async fn connect(
    dispatcher: &Dispatcher,
    placement: &Placement,
) -> Result<(UpSink, UpStream), UpstreamError> {
    match placement {
        Placement::Local { worker_session } => {
            let host = dispatcher
                .local_host()
                .ok_or(UpstreamError::NoInProcessWorker)?;
            let handle = host
                .session(worker_session)
                .ok_or(UpstreamError::SessionEnded)?;
            // Bounded towards the relay: when the browser is slow, the session's connection waits
            // here and, its frames being a latest-only watch, skips superseded frames.
            let (to_relay, from_worker) = futures::channel::mpsc::channel::<WsMessage>(2);
            let (to_worker, from_relay) = futures::channel::mpsc::channel::<WsMessage>(64);
            tokio::spawn(async move {
                if let Err(e) =
                    serve_connection(handle, to_relay, from_relay.map(Ok::<_, String>)).await
                {
                    tracing::debug!("in-process session connection ended: {e}");
                }
            });
            Ok((
                Box::pin(to_worker.sink_map_err(|e| e.to_string())),
                Box::pin(from_worker.map(Ok)),
            ))
        }
        Placement::Remote {
            worker_url,
            worker_session,
        } => {
            let (authority, _) = render_worker::cluster::split_url(worker_url)?;
            let url = format!("ws://{authority}/sessions/{worker_session}/ws");
            // Nagle's algorithm off (see `render_worker::cluster::no_delay`): commands are
            // small writes that must not wait for the worker's acknowledgement of the last.
            let (ws, _) = match tokio_tungstenite::connect_async_with_config(&url, None, true).await
            {
                Ok(c) => c,
                Err(source) => return Err(UpstreamError::Connect { url, source }),
            };
            let (sink, stream) = ws.split();
            let sink = sink.sink_map_err(|e| e.to_string()).with(|m: WsMessage| {
                futures::future::ready(Ok::<TMessage, String>(match m {
                    WsMessage::Text(t) => TMessage::text(t),
                    WsMessage::Binary(b) => TMessage::binary(b),
                    WsMessage::Close => TMessage::Close(None),
                }))
            });
            let stream = stream.filter_map(|m| {
                futures::future::ready(match m {
                    Ok(TMessage::Text(t)) => Some(Ok(WsMessage::Text(t.to_string()))),
                    Ok(TMessage::Binary(b)) => Some(Ok(WsMessage::Binary(b.to_vec()))),
                    Ok(TMessage::Close(_)) => Some(Ok(WsMessage::Close)),
                    Ok(_) => None,
                    Err(e) => Some(Err(e.to_string())),
                })
            });
            Ok((Box::pin(sink), Box::pin(stream)))
        }
    }
}

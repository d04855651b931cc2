//! The submitted technical result on its way from the worker to the learning records: the
//! worker's typed [`SubmitResult`] (from the submit's acknowledgement) becomes the records'
//! [`NewResult`], stored after the log it scores is durable.

use std::collections::BTreeMap;

use render_worker::session::{SubmitResult, sha256_hex};
use serde_json::json;

use super::{LiveSession, Placement, store};
use crate::records::RecordsState;
use crate::records::results::{NewResult, Reproducibility, store_session_result};

/// The learning-records form of a session's submit.
pub fn new_result(result: &SubmitResult, session_id: uuid::Uuid, worker: &str) -> NewResult {
    let r = &result.record;
    let is_sha = |h: &str| {
        h.len() == 64
            && h.bytes()
                .all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase())
    };
    let mut asset_hashes: BTreeMap<String, String> = r
        .asset_sha256
        .iter()
        .filter(|(_, h)| is_sha(h))
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    // The station file and the whole region (its fingerprint covers every asset hash, also
    // ones that are labels rather than file hashes, as in generated test regions).
    asset_hashes.insert(
        format!("station:{}", r.station_id),
        r.station_sha256.clone(),
    );
    let mut fingerprint = String::new();
    for (k, v) in &r.asset_sha256 {
        fingerprint.push_str(&format!("{k}={v}\n"));
    }
    asset_hashes.insert(
        format!("region:{}", r.region),
        sha256_hex(fingerprint.as_bytes()),
    );
    NewResult {
        measurements: result
            .measurements
            .iter()
            .map(|(k, v)| (k.clone(), *v))
            .collect(),
        reproducibility: Reproducibility {
            code_revision: r.code_revision.chars().take(100).collect(),
            asset_hashes,
            device_profile: json!({ "renderer": r.renderer, "worker": worker, "region_source": r.region_source }),
            imaging_settings: json!({ "modalities": r.modalities, "unavailable_modalities": r.unavailable_modalities }),
            interaction_log_ref: Some(format!(
                "live_sessions/{session_id} log_len={} log_sha256={} initial={} final={}",
                r.log_len, r.log_sha256, r.initial_state_sha256, r.final_state_sha256
            )),
            server_version: None,
            activity_upto_event_id: None,
            activity_event_count: None,
        },
    }
}

/// Stores the submit as the attempt's technical result; returns the message for the browser.
pub async fn store_result(
    records: &RecordsState,
    session: &LiveSession,
    placement: &Placement,
    result: Option<&SubmitResult>,
) -> serde_json::Value {
    let Some(result) = result else {
        return json!({ "type": "technical_result_error", "message": "the worker acknowledged the submit without a result" });
    };
    let req = new_result(result, session.id, &placement.worker_label());
    match store_session_result(
        records,
        session.learner_id,
        session.attempt_id,
        req,
        &result.rubric,
    )
    .await
    {
        Ok(view) => {
            let mut st = session.state.lock().await;
            st.result_id = Some(view.id);
            let frame = st.last_frame_sha256.clone();
            drop(st);
            let r = store::save_submitted(
                &records.pool,
                session.id,
                view.id,
                &result.record.final_state_sha256,
                frame.as_deref(),
            )
            .await;
            if let Err(e) = r {
                tracing::error!(session = %session.id, "saving the submitted session failed: {e}");
            }
            json!({ "type": "technical_result", "result": view })
        }
        Err(e) => {
            tracing::warn!(session = %session.id, "storing the technical result failed: {e}");
            json!({ "type": "technical_result_error", "message": e.to_string() })
        }
    }
}

//! An attempt's recorded session as the dispatch routes read it: the attempt as the caller may
//! see it, the newest recorded session (closed to the attempt's own learner while the attempt
//! is in progress) and its initial snapshot and log.

use render_worker::session::{LogEntry, SessionSnapshot};
use uuid::Uuid;

use super::route_state::DispatchState;
use super::store;
use crate::error::ApiError;
use crate::records::auth::CurrentUser;
use crate::records::authz::attempt_visible;

/// The attempt as the caller may see it: (learner, station, state, course); 404 when not
/// visible.
pub(super) async fn visible_attempt(
    state: &DispatchState,
    user: &CurrentUser,
    attempt_id: Uuid,
) -> Result<(Uuid, String, String, Uuid), ApiError> {
    sqlx::query_as(&format!(
        "SELECT a.learner_id, a.station_id, a.state, a.course_id FROM attempts a WHERE a.id = $3 AND {}",
        attempt_visible(1, 2)
    ))
    .bind(user.id)
    .bind(user.is_admin())
    .bind(attempt_id)
    .fetch_optional(&state.records.pool)
    .await?
    .ok_or_else(|| ApiError::NotFound("attempt".into()))
}

/// The newest recorded session of a visible attempt (submitted ones first).
pub(super) async fn recorded_session(
    state: &DispatchState,
    user: &CurrentUser,
    attempt_id: Uuid,
) -> Result<store::RecordedSession, ApiError> {
    let (learner, _, attempt_state, _) = visible_attempt(state, user, attempt_id).await?;
    // A replay scores the log: opened to the learner mid-attempt, it would tell them the tip's
    // distance from the target (see `disclosure`). Reviewers may look at any time.
    if learner == user.id && attempt_state == "in_progress" {
        return Err(ApiError::Conflict(
            "the replay of an attempt opens to its learner once the attempt is submitted".into(),
        ));
    }
    store::newest_recorded(&state.records.pool, attempt_id)
        .await?
        .ok_or_else(|| ApiError::NotFound("recorded session".into()))
}

/// A recorded session's initial snapshot (stored JSON) and its logged commands.
pub(super) async fn parse_recorded(
    state: &DispatchState,
    session_id: Uuid,
    initial: serde_json::Value,
) -> Result<(SessionSnapshot, Vec<LogEntry>), ApiError> {
    let initial = serde_json::from_value(initial)
        .map_err(|e| ApiError::Internal(format!("stored snapshot: {e}")))?;
    let log = store::load_commands(&state.records.pool, session_id)
        .await
        .map_err(|e| ApiError::Internal(format!("stored log: {e}")))?;
    Ok((initial, log))
}

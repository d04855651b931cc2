//! Sessions under hostile or absent clients: bursts of commands with
//! and without reading, a log write the database refuses for good, the relay after a submit
//! whose client left, idle sessions with their socket open, and the per-course limit. All
//! against the real database and the in-process worker on the demo station.

use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

use super::dispatch::{Client, DemoServer, Received, Ws, acked, demo_server};
use super::dispatch_support::disable_account;

/// Commands of a burst: a mix that changes the view, the technique and the clock, with every
/// 1,000th one out of range (it must be refused, in its place, with the field named).
fn burst_command(i: u64) -> Value {
    if i % 1000 == 500 {
        return json!({ "type": "carm_pose", "orbital_deg": 999, "angular_deg": 0 });
    }
    match i % 4 {
        0 => {
            json!({ "type": "carm_pose", "orbital_deg": (i % 90) as f64 - 45.0, "angular_deg": 0 })
        }
        1 => json!({ "type": "tick" }),
        2 => json!({ "type": "technique", "kvp": 80, "ma": 2.0 }),
        _ => json!({ "type": "shot" }),
    }
}

fn command_text(seq: u64, command: &Value) -> Message {
    Message::Text(
        json!({ "type": "command", "seq": seq, "command": command })
            .to_string()
            .into(),
    )
}

/// The answer to a command: `Some((seq, acked))` for an acknowledgement or an error with a seq.
fn answer(t: &Value) -> Option<(u64, bool)> {
    match t["type"].as_str()? {
        "ack" => Some((t["seq"].as_u64()?, true)),
        "error" => Some((t["seq"].as_u64()?, false)),
        _ => None,
    }
}

/// Checks the answers of a burst of `n`: one per command, in order, refusals only where the
/// command was bad, each naming its field.
fn check_burst_answers(texts: &[Value], n: u64) {
    let answers: Vec<(u64, bool, &Value)> = texts
        .iter()
        .filter_map(|t| answer(t).map(|(s, a)| (s, a, t)))
        .collect();
    assert_eq!(answers.len() as u64, n, "one answer per command");
    for (i, (seq, ok, t)) in answers.iter().enumerate() {
        let want = i as u64 + 1;
        assert_eq!(*seq, want, "answers in order: {t}");
        if want % 1000 == 500 {
            assert!(!ok, "the out-of-range command {want} is refused: {t}");
            assert_eq!(t["error"]["field"], "command.orbital_deg", "{t}");
        } else {
            assert!(ok, "command {want} is acknowledged: {t}");
        }
    }
}

async fn open_session(srv: &DemoServer, email: &str) -> (Client, String, Value, Ws) {
    let learner = Client::login(srv.addr, email).await;
    let (attempt, session) = learner.start_demo_attempt().await;
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws.until(&mut got, |r| !r.texts.is_empty()).await;
    assert_eq!(got.texts[0]["type"], "hello");
    (learner, attempt, session, ws)
}

/// Reads until the socket closes; the close frame's code and reason.
pub async fn close_frame(ws: &mut Ws, within: Duration) -> (u16, String) {
    ws.until_closed(&mut Received::default(), within)
        .await
        .expect("closed with a code")
}

/// Polls until the dispatcher no longer holds `id` and the worker's slot is free again.
async fn wait_freed(srv: &DemoServer, id: uuid::Uuid, within: Duration) {
    let deadline = Instant::now() + within;
    while Instant::now() < deadline {
        let live = srv.dispatcher.local_capacity().map_or(0, |(live, _)| live);
        if srv.dispatcher.session(id).is_none() && live == 0 {
            return;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let state = match srv.dispatcher.session(id) {
        Some(s) => {
            let st = s.state.lock().await;
            format!(
                "log {} durable {} result {:?} connections {}",
                st.log.len(),
                st.durable_len,
                st.result_id,
                s.connections.load(std::sync::atomic::Ordering::SeqCst)
            )
        }
        None => "forgotten".into(),
    };
    panic!(
        "session {id} still held ({state}): worker slots {:?}",
        srv.dispatcher.local_capacity()
    );
}

async fn audit_actions(srv: &DemoServer, id: &str) -> Vec<(String, Value)> {
    sqlx::query_as(
        "SELECT action, detail FROM audit_events WHERE object_type = 'live_session' AND object_id = $1 ORDER BY id",
    )
    .bind(id)
    .fetch_all(&srv.db.pool)
    .await
    .expect("audit entries")
}

/// Makes the test's database refuse a logged command `when` (SQL over `NEW`) with `errcode`,
/// standing for a database that refuses a write, for good or for a while.
async fn refuse_log_writes(srv: &DemoServer, when: &str, errcode: &str) {
    for sql in [
        format!(
            "CREATE FUNCTION refuse_write() RETURNS trigger LANGUAGE plpgsql AS $$
             BEGIN
                 IF {when} THEN
                     RAISE EXCEPTION 'refused by the test' USING ERRCODE = '{errcode}';
                 END IF;
                 RETURN NEW;
             END $$"
        ),
        "CREATE TRIGGER refuse_write BEFORE INSERT ON live_session_commands
         FOR EACH ROW EXECUTE FUNCTION refuse_write()"
            .to_string(),
    ] {
        sqlx::query(&sql).execute(&srv.db.pool).await.expect(&sql);
    }
}

/// 10,000 commands sent in one go without reading (before: about 80 applied,
/// then the connection stalled), then read: every command is answered, in order (acknowledged,
/// or refused naming the field), in bounded time, and the session takes another command.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_10000_commands_sent_without_reading_is_answered_in_order() {
    const N: u64 = 10_000;
    let srv = demo_server(true, None).await;
    let (_, _, _, mut ws) = open_session(&srv, "learner@demo.invalid").await;
    let started = Instant::now();
    let send = async {
        for seq in 1..=N {
            ws.ws
                .feed(command_text(seq, &burst_command(seq)))
                .await
                .expect("send");
        }
        ws.ws.flush().await.expect("flush");
    };
    tokio::time::timeout(Duration::from_secs(120), send)
        .await
        .expect("the server keeps reading a burst it can answer");
    let sent_s = started.elapsed().as_secs_f64();
    let mut got = Received::default();
    let read = ws.until(&mut got, |r| {
        r.texts.iter().filter(|t| answer(t).is_some()).count() as u64 == N
    });
    tokio::time::timeout(Duration::from_secs(300), read)
        .await
        .expect("every answer within 300 s");
    let last_s = started.elapsed().as_secs_f64();
    eprintln!(
        "burst without reading: {N} commands sent in {sent_s:.2} s, last answer after {last_s:.2} s, {} frames",
        got.frames.len()
    );
    check_burst_answers(&got.texts, N);
    // Still usable.
    ws.send(N + 1, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r).last() == Some(&(N + 1)))
        .await;
}

/// The same burst from a client that reads while it sends.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_10000_commands_read_while_sending_is_answered_in_order() {
    const N: u64 = 10_000;
    let srv = demo_server(true, None).await;
    let (_, _, _, ws) = open_session(&srv, "learner@demo.invalid").await;
    let (mut tx, mut rx) = ws.ws.split();
    let started = Instant::now();
    let reader = tokio::spawn(async move {
        let mut texts = Vec::new();
        while (texts.iter().filter(|t| answer(t).is_some()).count() as u64) < N {
            let m = tokio::time::timeout(Duration::from_secs(60), rx.next())
                .await
                .expect("a message within 60 s")
                .expect("open")
                .expect("ok");
            if let Message::Text(t) = m {
                texts.push(serde_json::from_str::<Value>(&t).unwrap());
            }
        }
        (texts, rx)
    });
    for seq in 1..=N {
        tx.send(command_text(seq, &burst_command(seq)))
            .await
            .expect("send");
    }
    let (texts, rx) = tokio::time::timeout(Duration::from_secs(300), reader)
        .await
        .expect("every answer within 300 s")
        .expect("reader");
    eprintln!(
        "burst read while sending: {N} commands, last answer after {:.2} s",
        started.elapsed().as_secs_f64()
    );
    check_burst_answers(&texts, N);
    let mut ws = Ws {
        ws: tx.reunite(rx).expect("one socket"),
    };
    let mut got = Received::default();
    ws.send(N + 1, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r) == [N + 1]).await;
}

/// A log write the database refuses for good (here a trigger of the test's
/// database stands for any permanent error) is not retried for ever: the session ends with close
/// code 1011 and a reason, an audit entry is written, its worker slot is freed, the refused
/// command was never acknowledged, and the attempt resumes from what was stored.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_log_write_refused_for_good_ends_the_session_with_a_reason_and_an_audit_entry() {
    let srv = demo_server(true, None).await;
    refuse_log_writes(
        &srv,
        "NEW.command ->> 'label' = 'poison'",
        "check_violation",
    )
    .await;
    let (learner, attempt, session, mut ws) = open_session(&srv, "learner@demo.invalid").await;
    let id: uuid::Uuid = session["session_id"].as_str().unwrap().parse().unwrap();
    let mut got = Received::default();
    ws.send(1, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r) == [1]).await;
    ws.send(
        2,
        json!({ "type": "annotate", "pixel": [10, 10], "label": "poison" }),
    )
    .await;
    let (code, reason) = close_frame(&mut ws, Duration::from_secs(30)).await;
    assert_eq!(code, server::dispatch::CLOSE_LOG_REFUSED, "{reason}");
    assert!(reason.contains("cannot be stored"), "{reason}");
    wait_freed(&srv, id, Duration::from_secs(10)).await;
    let audit = audit_actions(&srv, &id.to_string()).await;
    assert_eq!(audit.len(), 1, "{audit:?}");
    assert_eq!(audit[0].0, "session_ended_log_refused");
    assert!(
        audit[0].1["reason"]
            .as_str()
            .unwrap()
            .contains("refused by the test"),
        "{audit:?}"
    );
    // Resumed from the stored log: the refused command is not in it.
    let (s, resumed) = learner.session_of(&attempt).await;
    assert_eq!(
        (s, resumed["last_seq"].as_u64()),
        (200, Some(1)),
        "{resumed}"
    );
    let mut ws = learner.websocket(resumed["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws.send(2, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r) == [2]).await;
}

/// The other side of the rule above: a transient refusal (here a serialization failure the test's
/// database raises twice) is retried, and the command is acknowledged once it is stored.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_transient_log_write_failure_is_retried_and_then_acknowledged() {
    let srv = demo_server(true, None).await;
    sqlx::query("CREATE SEQUENCE flaky_writes")
        .execute(&srv.db.pool)
        .await
        .unwrap();
    let when = "NEW.command ->> 'label' = 'flaky' AND nextval('flaky_writes') <= 2";
    refuse_log_writes(&srv, when, "serialization_failure").await;
    let (_, _, _, mut ws) = open_session(&srv, "learner@demo.invalid").await;
    let mut got = Received::default();
    ws.send(1, json!({ "type": "shot" })).await;
    ws.send(
        2,
        json!({ "type": "annotate", "pixel": [10, 10], "label": "flaky" }),
    )
    .await;
    ws.send(3, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r) == [1, 2, 3]).await;
    let retried: i64 = sqlx::query_scalar("SELECT last_value FROM flaky_writes")
        .fetch_one(&srv.db.pool)
        .await
        .unwrap();
    assert!(retried >= 3, "refused twice, then stored: {retried}");
}

/// After a submit, a client that has gone does not keep the relay and its
/// worker slot.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn after_a_submit_whose_client_left_the_slot_is_freed() {
    let srv = demo_server(true, None).await;
    let (learner, attempt, session, mut ws) = open_session(&srv, "learner@demo.invalid").await;
    let id: uuid::Uuid = session["session_id"].as_str().unwrap().parse().unwrap();
    ws.send(1, json!({ "type": "shot" })).await;
    ws.send(2, json!({ "type": "submit" })).await;
    drop(ws);
    wait_freed(&srv, id, Duration::from_secs(30)).await;
    // The submit the browser sent before leaving was still logged and its result stored.
    let (s, detail) = learner
        .call("GET", &format!("/api/attempts/{attempt}"), None)
        .await;
    assert_eq!(s, 200);
    assert_eq!(detail["attempt"]["state"], "submitted", "{detail}");
}

/// A session that gets no command for the idle limit is closed even with its
/// websocket open (close code 4001 and a reason), audited, its slot freed; commands keep it
/// open; the attempt resumes from its log.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_connected_session_without_commands_is_closed_as_idle_and_resumes() {
    let srv = demo_server(true, None).await;
    srv.dispatcher.set_session_idle(Duration::from_millis(1200));
    let (learner, attempt, session, mut ws) = open_session(&srv, "learner@demo.invalid").await;
    let id: uuid::Uuid = session["session_id"].as_str().unwrap().parse().unwrap();
    let mut got = Received::default();
    // Driven: a command every 300 ms for three idle limits keeps it open. The idle limit
    // counts from the server's receipt of the last command, which comes after `last_sent`
    // however slow the machine is, so the close can never come sooner than the limit after it.
    let mut last_sent = Instant::now();
    for seq in 1..=12 {
        if seq > 1 {
            tokio::time::sleep(Duration::from_millis(300)).await;
        }
        last_sent = Instant::now();
        ws.send(seq, json!({ "type": "tick" })).await;
        ws.until(&mut got, |r| acked(r).last() == Some(&seq)).await;
    }
    assert!(
        srv.dispatcher.session(id).is_some(),
        "a driven session stays"
    );
    let (code, reason) = close_frame(&mut ws, Duration::from_secs(30)).await;
    assert_eq!(code, server::dispatch::CLOSE_IDLE, "{reason}");
    assert!(reason.contains("no command"), "{reason}");
    let quiet = last_sent.elapsed();
    assert!(quiet >= Duration::from_millis(1200), "closed after {quiet:?}");
    wait_freed(&srv, id, Duration::from_secs(10)).await;
    let audit = audit_actions(&srv, &id.to_string()).await;
    assert_eq!(audit.len(), 1, "{audit:?}");
    assert_eq!(audit[0].0, "session_closed_idle");
    assert_eq!(audit[0].1["connected"], 1, "{audit:?}");
    let (s, resumed) = learner.session_of(&attempt).await;
    assert_eq!(
        (s, resumed["last_seq"].as_u64()),
        (200, Some(12)),
        "{resumed}"
    );
}

/// One course cannot take the render worker from the others: at the
/// per-course limit a new session is refused with 429 naming the course limit, even for a user
/// under the per-user limit, while a session in another course still opens.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_course_holds_at_most_the_per_course_limit_of_sessions() {
    let srv = demo_server(true, None).await;
    srv.dispatcher.set_sessions_per_course(2);
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let other = Client::login(srv.addr, "learner2@demo.invalid").await;
    let (first, _) = learner.start_demo_attempt().await;
    other.start_demo_attempt().await;
    let (_, (status, body)) = learner.try_demo_attempt().await;
    assert_eq!(status, 429, "{body}");
    assert_eq!(body["error"]["code"], "session_limit");
    assert_eq!(body["error"]["scope"], "course");
    assert_eq!(body["error"]["setting"], "PAINSIM_SESSIONS_PER_COURSE");
    assert_eq!(body["error"]["limit"], 2);
    let message = body["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("at most 2 live sessions per course"),
        "{message}"
    );
    // The running session is still returned.
    let (s, again) = learner.session_of(&first).await;
    assert_eq!(s, 200, "{again}");
    // Another course is unaffected.
    let course = uuid::Uuid::new_v4();
    sqlx::query("INSERT INTO courses (id, code, title) VALUES ($1, 'OTHER-1', 'Other course')")
        .bind(course)
        .execute(&srv.db.pool)
        .await
        .unwrap();
    sqlx::query(
        "INSERT INTO course_members (course_id, user_id, role)
         SELECT $1, id, 'learner' FROM users WHERE email = 'learner@demo.invalid'",
    )
    .bind(course)
    .execute(&srv.db.pool)
    .await
    .unwrap();
    let id = learner.new_attempt_in(&json!(course)).await;
    let (s, session) = learner.session_of(&id).await;
    assert_eq!(s, 201, "{session}");
    // The per-user limit is named as such.
    let (_, (status, body)) = learner.try_demo_attempt().await;
    assert_eq!(status, 429, "{body}");
    assert_eq!(body["error"]["scope"], "user", "{body}");
}

/// A revoked account's open session ends with close code 4003 and a reason instead of being
/// restored on another worker, and its slot is freed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_revoked_accounts_open_session_closes_with_a_reason() {
    let srv = demo_server(true, None).await;
    let (_, _, session, mut ws) = open_session(&srv, "learner@demo.invalid").await;
    let id: uuid::Uuid = session["session_id"].as_str().unwrap().parse().unwrap();
    disable_account(srv.addr, &srv.db.pool, "learner@demo.invalid").await;
    let (code, reason) = close_frame(&mut ws, Duration::from_secs(30)).await;
    assert_eq!(code, server::dispatch::CLOSE_REVOKED, "{reason}");
    assert!(reason.contains("log in again"), "{reason}");
    wait_freed(&srv, id, Duration::from_secs(10)).await;
}

//! `/healthz` through the real router against a fresh database.

use axum::body::Body;
use axum::http::{Request, StatusCode};
use server::test_support::test_db;
use server::{AppState, Config, app, workers::Workers};
use tower::ServiceExt;

async fn get_json(router: axum::Router, uri: &str) -> (StatusCode, serde_json::Value) {
    let resp = router.oneshot(Request::get(uri).body(Body::empty()).unwrap()).await.unwrap();
    let status = resp.status();
    let bytes = axum::body::to_bytes(resp.into_body(), 1 << 20).await.unwrap();
    (status, serde_json::from_slice(&bytes).unwrap_or(serde_json::Value::Null))
}

#[tokio::test]
async fn healthz_reports_database_and_worker() {
    let db = test_db().await;
    sqlx::query("INSERT INTO installation (id) VALUES (gen_random_uuid())").execute(&db.pool).await.unwrap();
    let config = Config::from_lookup(|_| None).unwrap();
    let workers = Workers::start_in_process();
    let state = AppState { pool: db.pool.clone(), embedded_db: true, workers: workers.clone(), dispatcher: None, config };
    // Wait for the worker's GPU self-test (lavapipe compiles the shader on first use).
    let w = workers.clone();
    tokio::task::spawn_blocking(move || w.wait_until_settled(std::time::Duration::from_secs(60))).await.unwrap();
    let (status, body) = get_json(app(state.clone()), "/healthz").await;
    assert_eq!(body["database"]["ready"], true, "{body}");
    assert!(body["database"]["installation_id"].is_string(), "{body}");
    match workers.status().state {
        "ready" => assert_eq!(status, StatusCode::OK, "{body}"),
        other => {
            // No adapter on this machine: the report must say so, with 503.
            assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE, "{body}");
            assert_eq!(body["render_worker"]["state"], other);
            assert!(std::env::var_os("REQUIRE_GPU").is_none(), "REQUIRE_GPU is set but the worker is {other}: {body}");
            eprintln!("GPU TEST SKIPPED: render worker {other}: {}", body["render_worker"]["error"]);
        }
    }

    // A broken database is reported as not ready, with 503 and no driver detail in the body.
    db.pool.close().await;
    let (status, body) = get_json(app(state), "/healthz").await;
    assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(body["database"]["ready"], false);
    assert!(!body.to_string().to_lowercase().contains("pool"), "no internal detail leaks: {body}");
}

#[tokio::test]
async fn web_client_is_served() {
    let db = test_db().await;
    let workers = Workers::start_in_process();
    let state = AppState { pool: db.pool, embedded_db: true, workers: workers.clone(), dispatcher: None, config: Config::from_lookup(|_| None).unwrap() };
    let resp = app(state).oneshot(Request::get("/").body(Body::empty()).unwrap()).await.unwrap();
    assert_eq!(resp.status(), StatusCode::OK);
    let bytes = axum::body::to_bytes(resp.into_body(), 1 << 20).await.unwrap();
    assert!(String::from_utf8_lossy(&bytes).contains("<main"));
    tokio::task::spawn_blocking(move || workers.wait_until_settled(std::time::Duration::from_secs(60))).await.unwrap();
}

#[tokio::test]
async fn each_test_gets_its_own_database() {
    let a = test_db().await;
    let b = test_db().await;
    assert_ne!(a.name, b.name);
    sqlx::query("INSERT INTO installation (id) VALUES (gen_random_uuid())").execute(&a.pool).await.unwrap();
    let in_b: i64 = sqlx::query_scalar("SELECT count(*) FROM installation").fetch_one(&b.pool).await.unwrap();
    assert_eq!(in_b, 0);
}

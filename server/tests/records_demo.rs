//! Demo accounts (published passwords) only where they are safe: on a
//! loopback bind with the embedded database, or when asked for explicitly; never by default on
//! a public bind, and start-up says which.

use server::test_support::test_db;

use crate::records_support::test_config;

async fn demo_users(overrides: &[(&str, &str)], embedded_db: bool) -> (i64, Option<String>) {
    let db = test_db().await;
    let config = test_config(overrides);
    let notice = server::records::prepare(&db.pool, &config.records, embedded_db)
        .await
        .expect("prepare");
    let n: i64 = sqlx::query_scalar("SELECT count(*) FROM users WHERE email LIKE '%@demo.invalid'")
        .fetch_one(&db.pool)
        .await
        .unwrap();
    (n, notice)
}

#[tokio::test]
async fn demo_accounts_only_on_loopback_or_when_asked() {
    // Loopback bind (the default) with the embedded database: created, and announced.
    let (n, notice) = demo_users(&[("PAINSIM_BIND", "127.0.0.1:8080")], true).await;
    assert!(n > 0);
    assert!(notice.is_some());
    // A public bind: not created, and start-up says why and how to change it.
    let (n, notice) = demo_users(&[("PAINSIM_BIND", "0.0.0.0:8080")], true).await;
    assert_eq!(n, 0);
    let notice = notice.expect("a start-up notice");
    assert!(
        notice.contains("not created") && notice.contains("PAINSIM_DEMO_ACCOUNTS"),
        "{notice}"
    );
    // Asked for explicitly: created on a public bind too; refused explicitly: not on loopback.
    let (n, _) = demo_users(
        &[
            ("PAINSIM_BIND", "0.0.0.0:8080"),
            ("PAINSIM_DEMO_ACCOUNTS", "true"),
        ],
        true,
    )
    .await;
    assert!(n > 0);
    let (n, _) = demo_users(
        &[
            ("PAINSIM_BIND", "127.0.0.1:8080"),
            ("PAINSIM_DEMO_ACCOUNTS", "false"),
        ],
        true,
    )
    .await;
    assert_eq!(n, 0);
    // An external database by default: none (as before).
    let (n, notice) = demo_users(&[("PAINSIM_BIND", "127.0.0.1:8080")], false).await;
    assert_eq!((n, notice), (0, None));
}

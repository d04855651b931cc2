//! Approval flow end to end: attempt -> activity -> technical result -> faculty return with a
//! comment -> resubmission -> approval, with the audit trail, the append-only tables and the
//! rules that nobody approves their own attempt and that a technical "met" is not approval.

use axum::http::{Method, StatusCode};
use serde_json::json;
use server::records::auth::Role;
use server::records::totp;

use crate::records_support::{Session, TestApp, facet_measurements_met};

#[tokio::test]
async fn attempt_result_return_resubmit_approve_with_audit_trail() {
    let app = TestApp::new(&[]).await;
    let learner = app.user("learner@example.org", Role::Learner).await;
    let faculty = app.user("faculty@example.org", Role::Faculty).await;
    let course = app.course("SPINE-1").await;
    app.member(course, learner, "learner").await;
    app.member(course, faculty, "faculty").await;
    let ls = app.login("learner@example.org", None).await;

    // 1. The learner opens an attempt and works; the server records engagement.
    let r = app
        .send(
            Method::POST,
            "/api/attempts",
            Some(&ls),
            Some(json!({ "course_id": course, "station_id": "l4-l5-left-facet" })),
        )
        .await;
    assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
    assert_eq!(r.json["state"], "in_progress");
    let attempt = r.json["id"].as_str().unwrap().to_owned();
    for kind in [
        "page_viewed",
        "view_changed",
        "image_acquired",
        "needle_adjusted",
        "image_acquired",
        "injection",
    ] {
        let r = app
            .send(
                Method::POST,
                &format!("/api/attempts/{attempt}/activity"),
                Some(&ls),
                Some(json!({ "kind": kind, "detail": { "n": 1 } })),
            )
            .await;
        assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
    }
    // Reading is engagement only: a client cannot claim a submission by posting activity.
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{attempt}/activity"),
            Some(&ls),
            Some(json!({ "kind": "submission" })),
        )
        .await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST);

    // 2. A first submission missing one measurement: technical result "incomplete", partial score.
    let mut partial = facet_measurements_met();
    partial
        .as_object_mut()
        .unwrap()
        .remove("intra_articular_spread_bool");
    let r = app.submit(learner, &attempt, partial).await;
    assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
    assert_eq!(r.json["outcome"], "incomplete");
    assert_eq!(r.json["score"], 1.0);
    assert_eq!(
        r.json["detail"]["incomplete_criteria"],
        json!(["intra_articular_contrast"])
    );
    assert_eq!(r.json["station_revision"], 2);
    assert_eq!(
        r.json["reproducibility"]["activity_event_count"], 7,
        "station_opened + 6 reported events"
    );
    assert!(
        r.json["notice"]
            .as_str()
            .unwrap()
            .contains("not a certification of clinical competency")
    );
    let first_result = r.json["id"].as_str().unwrap().to_owned();
    // Submitted: no second submission until reviewed.
    let r = app.submit(learner, &attempt, facet_measurements_met()).await;
    assert_eq!(r.status, StatusCode::CONFLICT);

    // 3. The learner cannot approve (their own attempt, and not a reviewer).
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{attempt}/review"),
            Some(&ls),
            Some(json!({ "decision": "approve" })),
        )
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);

    // 4. Faculty without TOTP cannot review while TOTP is mandatory; they enrol through the API.
    let fs = app.login("faculty@example.org", None).await;
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{attempt}/review"),
            Some(&fs),
            Some(json!({ "decision": "return", "comment": "x" })),
        )
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    assert!(
        r.json["error"]["message"]
            .as_str()
            .unwrap()
            .contains("TOTP"),
        "{}",
        r.text
    );
    let r = app
        .send(Method::POST, "/api/auth/totp/enroll", Some(&fs), None)
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    assert!(
        r.json["otpauth_url"]
            .as_str()
            .unwrap()
            .starts_with("otpauth://totp/")
    );
    let secret: Vec<u8> = sqlx::query_scalar("SELECT totp_pending FROM users WHERE id = $1")
        .bind(faculty)
        .fetch_one(app.pool())
        .await
        .unwrap();
    let now = totp::unix_now();
    let r = app
        .send(
            Method::POST,
            "/api/auth/totp/confirm",
            Some(&fs),
            Some(json!({ "code": totp::code_at(&secret, now) })),
        )
        .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
    // From now on a password alone does not log in.
    let r = app.send(Method::POST, "/api/auth/login", None, Some(json!({ "email": "faculty@example.org", "password": crate::records_support::PASSWORD }))).await;
    assert_eq!(
        (r.status, r.json["error"]["code"].as_str()),
        (StatusCode::UNAUTHORIZED, Some("totp_required"))
    );
    // A fresh login with the next step's code (the confirmed one cannot be replayed).
    let fs: Session = app
        .login(
            "faculty@example.org",
            Some(totp::code_at(&secret, now + totp::STEP_S)),
        )
        .await;

    // 5. Return with a comment (a return needs one).
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{attempt}/review"),
            Some(&fs),
            Some(json!({ "decision": "return", "comment": "  " })),
        )
        .await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST);
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{attempt}/review"),
            Some(&fs),
            Some(json!({ "decision": "return", "comment": "Document the arthrogram." })),
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    assert_eq!(
        (r.json["decision"].as_str(), r.json["result_id"].as_str()),
        (Some("returned"), Some(first_result.as_str()))
    );

    // 6. The learner resubmits with every measurement: technical "met" -- still not approved.
    let r = app.submit(learner, &attempt, facet_measurements_met()).await;
    assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
    assert_eq!(
        (r.json["outcome"].as_str(), r.json["seq"].as_i64()),
        (Some("met"), Some(2))
    );
    let detail = app
        .send(
            Method::GET,
            &format!("/api/attempts/{attempt}"),
            Some(&ls),
            None,
        )
        .await;
    assert_eq!(
        detail.json["attempt"]["state"], "submitted",
        "a technical met is not an approval"
    );

    // 7. Faculty sees it in the filtered queue and the CSV, then approves.
    let q = app
        .send(
            Method::GET,
            &format!("/api/reviews?station_id=l4-l5-left-facet&course_id={course}&state=submitted"),
            Some(&fs),
            None,
        )
        .await;
    assert_eq!(q.json.as_array().unwrap().len(), 1, "{}", q.text);
    let q = app
        .send(
            Method::GET,
            "/api/reviews?station_id=l4-left-transforaminal",
            Some(&fs),
            None,
        )
        .await;
    assert_eq!(q.json.as_array().unwrap().len(), 0);
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{attempt}/review"),
            Some(&fs),
            Some(json!({ "decision": "approve", "comment": "Good technique." })),
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{attempt}/review"),
            Some(&fs),
            Some(json!({ "decision": "approve" })),
        )
        .await;
    assert_eq!(r.status, StatusCode::CONFLICT, "approved is final");
    let csv = app
        .send(
            Method::GET,
            "/api/reviews/export.csv?state=approved",
            Some(&fs),
            None,
        )
        .await;
    assert_eq!(csv.status, StatusCode::OK);
    assert!(
        csv.headers["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/csv")
    );
    let lines: Vec<&str> = csv.text.trim_end().split("\r\n").collect();
    assert_eq!(lines.len(), 2, "{}", csv.text);
    assert!(lines[0].starts_with("attempt_id,learner_email"));
    assert!(
        lines[1].contains("\"approved\"")
            && lines[1].contains("\"met\"")
            && lines[1].contains("Good technique.")
            && lines[1].contains("faculty@example.org"),
        "{}",
        lines[1]
    );

    // 8. Closed: no more activity or results.
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{attempt}/activity"),
            Some(&ls),
            Some(json!({ "kind": "view_changed" })),
        )
        .await;
    assert_eq!(r.status, StatusCode::CONFLICT);

    // 9. The audit trail shows each step, in order, with who did it.
    let d = app
        .send(
            Method::GET,
            &format!("/api/attempts/{attempt}"),
            Some(&ls),
            None,
        )
        .await
        .json;
    let trail: Vec<(String, String)> = d["audit"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["action"].as_str().unwrap().to_owned(),
                e["actor_email"].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    let l = "learner@example.org".to_string();
    let f = "faculty@example.org".to_string();
    assert_eq!(
        trail,
        vec![
            ("attempt_created".into(), l.clone()),
            ("result_submitted".into(), l.clone()),
            ("attempt_returned".into(), f.clone()),
            ("result_submitted".into(), l.clone()),
            ("attempt_approved".into(), f.clone()),
        ]
    );
    assert_eq!(d["reviews"].as_array().unwrap().len(), 2);
    assert_eq!(d["results"].as_array().unwrap().len(), 2);
    assert_eq!(d["attempt"]["state"], "approved");
    let kinds: Vec<String> = app
        .send(
            Method::GET,
            &format!("/api/attempts/{attempt}/activity"),
            Some(&ls),
            None,
        )
        .await
        .json
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["kind"].as_str().unwrap().to_owned())
        .collect();
    assert_eq!(kinds.first().map(String::as_str), Some("station_opened"));
    assert_eq!(kinds.iter().filter(|k| *k == "submission").count(), 2);

    // 10. History is append-only, even for direct SQL.
    for sql in [
        "UPDATE reviews SET comment = 'edited'",
        "DELETE FROM audit_events",
        "UPDATE technical_results SET outcome = 'met'",
        "DELETE FROM activity_events",
        "TRUNCATE reviews CASCADE",
    ] {
        let e = sqlx::query(sql).execute(app.pool()).await.expect_err(sql);
        assert!(e.to_string().contains("append-only"), "{sql}: {e}");
    }
}

#[tokio::test]
async fn nobody_approves_their_own_attempt_and_bulk_approval_is_all_or_nothing() {
    let app = TestApp::new(&[("PAINSIM_REQUIRE_TOTP_FOR_APPROVAL", "false")]).await;
    let admin = app.user("admin@example.org", Role::Admin).await;
    let learner = app.user("l@example.org", Role::Learner).await;
    let faculty = app.user("f@example.org", Role::Faculty).await;
    let course = app.course("C").await;
    app.member(course, learner, "learner").await;
    app.member(course, faculty, "faculty").await;
    let ls = app.login("l@example.org", None).await;
    let mut attempts = Vec::new();
    for _ in 0..3 {
        let r = app
            .send(
                Method::POST,
                "/api/attempts",
                Some(&ls),
                Some(json!({ "course_id": course, "station_id": "l4-left-transforaminal" })),
            )
            .await;
        let id = r.json["id"].as_str().unwrap().to_owned();
        let r = app.submit(learner, &id, json!({ "tip_to_target_mm": 2.0 })).await;
        assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
        attempts.push(id);
    }
    // An attempt whose learner is the admin (membership rules never allow it, so the row is made
    // by hand): the own-attempt rule still holds for the admin, who may review everything else.
    sqlx::query("INSERT INTO course_members (course_id, user_id, role) VALUES ($1, $2, 'learner')")
        .bind(course)
        .bind(admin)
        .execute(app.pool())
        .await
        .unwrap();
    let as_ = app.login("admin@example.org", None).await;
    let r = app
        .send(
            Method::POST,
            "/api/attempts",
            Some(&as_),
            Some(json!({ "course_id": course, "station_id": "l4-left-transforaminal" })),
        )
        .await;
    let own = r.json["id"].as_str().unwrap().to_owned();
    let r = app.submit(admin, &own, json!({})).await;
    assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{own}/review"),
            Some(&as_),
            Some(json!({ "decision": "approve" })),
        )
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN, "{}", r.text);
    assert!(r.text.contains("their own attempt"));

    // Bulk: one bad id (the admin's own) fails the whole request; nothing is recorded.
    let before = app.counts().await;
    let mut ids: Vec<_> = attempts.clone();
    ids.push(own.clone());
    let r = app
        .send(
            Method::POST,
            "/api/reviews/bulk-approve",
            Some(&as_),
            Some(json!({ "attempt_ids": ids })),
        )
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN, "{}", r.text);
    assert_eq!(app.counts().await, before);
    // Without it, faculty approves all three at once.
    let fs = app.login("f@example.org", None).await;
    let r = app
        .send(
            Method::POST,
            "/api/reviews/bulk-approve",
            Some(&fs),
            Some(json!({ "attempt_ids": attempts, "comment": "batch" })),
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    assert_eq!(r.json["approved"].as_array().unwrap().len(), 3);
    let approved: i64 =
        sqlx::query_scalar("SELECT count(*) FROM attempts WHERE state = 'approved'")
            .fetch_one(app.pool())
            .await
            .unwrap();
    assert_eq!(approved, 3);
    let audit = app
        .send(
            Method::GET,
            "/api/audit?object_type=attempt",
            Some(&as_),
            None,
        )
        .await;
    let approvals = audit
        .json
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "attempt_approved")
        .count();
    assert_eq!(approvals, 3);
}

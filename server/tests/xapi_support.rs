//! Helpers of the LRS tests: the production app over a fresh database with an admin, LRS
//! credentials created through the admin API, and requests with HTTP Basic and the version header.

use axum::body::Body;
use axum::http::{Method, Request, StatusCode};
use base64::Engine;
use serde_json::{Value, json};
use server::records::auth::Role;

use crate::records_support::{Response, Session, TestApp};

/// An LRS credential as created by the admin API.
#[derive(Debug, Clone)]
pub struct Cred {
    /// Credential id.
    pub id: String,
    /// Basic user name.
    pub key: String,
    /// Basic password.
    pub secret: String,
    /// Its authority agent.
    pub authority: Value,
}

impl Cred {
    /// The `Authorization` header value.
    pub fn basic(&self) -> String {
        let raw = format!("{}:{}", self.key, self.secret);
        format!(
            "Basic {}",
            base64::engine::general_purpose::STANDARD.encode(raw)
        )
    }
}

/// The app, its admin's session and a read-write credential.
pub struct Lrs {
    /// The app.
    pub app: TestApp,
    /// The admin's session.
    pub admin: Session,
    /// A read-write credential.
    pub cred: Cred,
}

impl Lrs {
    /// A fresh database, an admin and one read-write credential.
    pub async fn new() -> Lrs {
        let app = TestApp::new(&[]).await;
        let email = format!("admin-{}@example.org", uuid::Uuid::new_v4().simple());
        app.user(&email, Role::Admin).await;
        let admin = app.login(&email, None).await;
        let mut lrs = Lrs {
            app,
            admin,
            cred: Cred {
                id: String::new(),
                key: String::new(),
                secret: String::new(),
                authority: Value::Null,
            },
        };
        lrs.cred = lrs.credential("LMS read-write", true, true).await;
        lrs
    }

    /// Sends an admin API request with the admin's session.
    pub async fn as_admin(&self, method: Method, uri: &str, body: Option<Value>) -> Response {
        self.app.send(method, uri, Some(&self.admin), body).await
    }

    /// Creates a credential from an admin's request body (201 asserted).
    pub async fn credential_from(&self, body: Value) -> Cred {
        let r = self
            .as_admin(Method::POST, "/api/admin/lrs-credentials", Some(body))
            .await;
        assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
        Cred {
            id: r.json["id"].as_str().unwrap().to_owned(),
            key: r.json["key"].as_str().unwrap().to_owned(),
            secret: r.json["secret"].as_str().unwrap().to_owned(),
            authority: r.json["authority"].clone(),
        }
    }

    /// Creates a credential through the admin API.
    pub async fn credential(&self, name: &str, read: bool, write: bool) -> Cred {
        let access = match (read, write) {
            (true, true) => "read_write",
            (true, false) => "read",
            _ => "write",
        };
        self.credential_from(json!({ "name": name, "access": access }))
            .await
    }

    /// Sends an LRS request with `cred` (if any), the version header 2.0.0, the extra `headers`
    /// and a raw body with its content type.
    pub async fn raw(
        &self,
        method: Method,
        uri: &str,
        cred: Option<&Cred>,
        headers: &[(&str, &str)],
        body: Option<(&str, Vec<u8>)>,
    ) -> Response {
        let mut req = Request::builder().method(method).uri(uri);
        req = req.header("x-experience-api-version", "2.0.0");
        if let Some(c) = cred {
            req = req.header("authorization", c.basic());
        }
        for (k, v) in headers {
            req = req.header(*k, *v);
        }
        let body = match body {
            Some((ct, bytes)) => {
                req = req.header("content-type", ct);
                Body::from(bytes)
            }
            None => Body::empty(),
        };
        self.app.request(req.body(body).unwrap()).await
    }

    /// Sends JSON with the read-write credential.
    pub async fn send(&self, method: Method, uri: &str, body: Option<Value>) -> Response {
        let body = body.map(|b| ("application/json", b.to_string().into_bytes()));
        self.raw(method, uri, Some(&self.cred), &[], body).await
    }
}

//! LTI 1.3 and LTI Advantage against a real platform process: `server/tests/lti_platform/
//! platform.py` (the `lti1p3platform` package, installed by `.ci/install-deps test` into
//! `target/lti-platform-venv`) on loopback, and the app served on a loopback TCP listener.
//!
//! The flow test drives OIDC login → launch → deep linking → score publication (PendingManual,
//! then FullyGraded after approval) → result read-back → NRPS course fill → key rotation over
//! real HTTP; one test per refused launch checks the error and that no session was opened.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::Stdio;
use std::time::Duration;

use axum::http::{Method, StatusCode};
use serde_json::{Value, json};
use server::lti::services::{SCOPES_AGS, access_token, spawn_score_pump};
use server::lti::{LtiState, platforms};
use server::outbox::Outbox;
use server::records::auth::Role;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};
use uuid::Uuid;

use crate::records_support::{Session, TestApp, facet_measurements_met};

/// The station the deep link chooses.
const STATION: &str = "l4-l5-left-facet";

/// How long a score may take from the result to the platform (our choice: the pump looks every
/// 0.5 s and the outbox delivers at once; 20 s absorbs a loaded 2-core CI machine).
const DELIVERY_LIMIT: Duration = Duration::from_secs(20);

fn python() -> PathBuf {
    let p =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/lti-platform-venv/bin/python");
    assert!(
        p.exists(),
        "{} is missing: run `.ci/install-deps test` to install lti1p3platform",
        p.display()
    );
    p
}

/// The tool (the app on a loopback port), the platform process, an admin session, the
/// registered platform.
pub struct Lti {
    pub app: TestApp,
    pub tool: String,
    pub platform_url: String,
    _platform: Child,
    pub admin: Session,
    pub platform_id: Uuid,
    pub http: reqwest::Client,
}

impl Lti {
    pub async fn start(overrides: &[(&str, &str)]) -> Lti {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let tool = format!("http://{addr}");
        let mut env = vec![("PAINSIM_PUBLIC_URL", tool.as_str())];
        env.extend_from_slice(overrides);
        let app = TestApp::new(&env).await;
        let router = app.router.clone();
        tokio::spawn(async move {
            axum::serve(
                listener,
                router.into_make_service_with_connect_info::<SocketAddr>(),
            )
            .await
            .unwrap();
        });
        let script =
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/lti_platform/platform.py");
        let mut platform = Command::new(python())
            .arg(&script)
            .arg(&tool)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .kill_on_drop(true)
            .spawn()
            .expect("the platform process starts");
        let mut first = String::new();
        BufReader::new(platform.stdout.take().unwrap())
            .read_line(&mut first)
            .await
            .unwrap();
        let info: Value = serde_json::from_str(&first).expect("the platform prints its address");
        let platform_url = info["issuer"].as_str().unwrap().to_owned();
        app.user("lti-admin@example.org", Role::Admin).await;
        let admin = app.login("lti-admin@example.org", None).await;
        let r = app
            .send(
                Method::POST,
                "/api/admin/lti/platforms",
                Some(&admin),
                Some(json!({
                    "name": "lti1p3platform on loopback",
                    "issuer": platform_url,
                    "client_id": info["client_id"],
                    "deployment_ids": [info["deployment_id"]],
                    "auth_url": format!("{platform_url}/auth"),
                    "token_url": format!("{platform_url}/token"),
                    "jwks_url": format!("{platform_url}/jwks"),
                })),
            )
            .await;
        assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
        let platform_id = r.json["id"].as_str().unwrap().parse().unwrap();
        let http = reqwest::Client::builder()
            .redirect(reqwest::redirect::Policy::none())
            .build()
            .unwrap();
        Lti {
            app,
            tool,
            platform_url,
            _platform: platform,
            admin,
            platform_id,
            http,
        }
    }

    /// The LTI state the server's background work uses, over the test's database.
    pub fn state(&self) -> LtiState {
        LtiState::new(
            self.app.pool().clone(),
            server::records::RecordsState::from_parts(
                self.app.pool().clone(),
                self.app.config.clone(),
            ),
            &self.tool,
        )
    }

    pub async fn sessions(&self) -> i64 {
        sqlx::query_scalar("SELECT count(*) FROM auth_sessions")
            .fetch_one(self.app.pool())
            .await
            .unwrap()
    }
}

/// A browser: one cookie jar for the loopback host (browsers do not separate ports).
#[derive(Default)]
pub struct Browser {
    jar: BTreeMap<String, String>,
}

/// A response as the browser saw it.
pub struct Page {
    pub status: u16,
    pub headers: reqwest::header::HeaderMap,
    pub text: String,
}

impl Page {
    pub fn location(&self) -> String {
        self.headers
            .get("location")
            .expect("a redirect")
            .to_str()
            .unwrap()
            .to_owned()
    }

    pub fn json(&self) -> Value {
        serde_json::from_str(&self.text).unwrap_or(Value::Null)
    }

    /// The value of `name="..." value="..."` hidden inputs and the form's action (HTML we and the
    /// test platform write: attributes in this order, values escaped).
    pub fn form(&self) -> (String, BTreeMap<String, String>) {
        let attr = |tag: &str, name: &str| {
            let start = tag.find(&format!("{name}=\""))? + name.len() + 2;
            Some(unescape(&tag[start..start + tag[start..].find('"')?]))
        };
        let form_tag = self.text.split("<form").nth(1).expect("a form");
        let action = attr(form_tag.split('>').next().unwrap(), "action").expect("an action");
        let mut fields = BTreeMap::new();
        for input in form_tag.split("<input").skip(1) {
            let tag = input.split('>').next().unwrap();
            if let (Some(n), Some(v)) = (attr(tag, "name"), attr(tag, "value")) {
                fields.insert(n, v);
            }
        }
        (action, fields)
    }

    pub fn cookie_set(&self, name: &str) -> bool {
        self.headers
            .get_all("set-cookie")
            .iter()
            .filter_map(|v| v.to_str().ok())
            .any(|c| c.starts_with(&format!("{name}=")) && !c.starts_with(&format!("{name}=;")))
    }
}

fn unescape(s: &str) -> String {
    s.replace("&quot;", "\"")
        .replace("&#39;", "'")
        .replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&amp;", "&")
}

impl Browser {
    async fn take(&mut self, r: reqwest::Response) -> Page {
        for c in r
            .headers()
            .get_all("set-cookie")
            .iter()
            .filter_map(|v| v.to_str().ok())
        {
            let pair = c.split(';').next().unwrap();
            let (k, v) = pair.split_once('=').unwrap();
            if v.is_empty() || c.contains("Max-Age=0") {
                self.jar.remove(k);
            } else {
                self.jar.insert(k.to_owned(), v.to_owned());
            }
        }
        let status = r.status().as_u16();
        let headers = r.headers().clone();
        Page {
            status,
            headers,
            text: r.text().await.unwrap(),
        }
    }

    fn cookies(&self) -> String {
        self.jar
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join("; ")
    }

    pub async fn get(&mut self, http: &reqwest::Client, url: &str) -> Page {
        let r = http
            .get(url)
            .header("cookie", self.cookies())
            .send()
            .await
            .unwrap();
        self.take(r).await
    }

    pub async fn post(
        &mut self,
        http: &reqwest::Client,
        url: &str,
        form: &BTreeMap<String, String>,
    ) -> Page {
        let r = http
            .post(url)
            .header("cookie", self.cookies())
            .form(form)
            .send()
            .await
            .unwrap();
        self.take(r).await
    }

    /// The session the tool opened in this browser.
    pub fn session(&self) -> Session {
        Session {
            token: self
                .jar
                .get("painsim_session")
                .expect("a session cookie")
                .clone(),
            csrf: self.jar.get("painsim_csrf").expect("a CSRF cookie").clone(),
        }
    }

    /// Starts a launch at the platform and follows it to the tool's launch endpoint: returns the
    /// platform's auto-post form (action and fields) and the tool's answer to it.
    pub async fn launch(
        &mut self,
        lti: &Lti,
        query: &str,
    ) -> (String, BTreeMap<String, String>, Page) {
        let start = self
            .get(&lti.http, &format!("{}/start?{query}", lti.platform_url))
            .await;
        assert_eq!(start.status, 302, "{}", start.text);
        let login = self.get(&lti.http, &start.location()).await;
        assert_eq!(login.status, 302, "the tool's login: {}", login.text);
        assert!(
            login
                .location()
                .starts_with(&format!("{}/auth?", lti.platform_url))
        );
        let auth = self.get(&lti.http, &login.location()).await;
        assert_eq!(
            auth.status, 200,
            "the platform's auth endpoint: {}",
            auth.text
        );
        let (action, fields) = auth.form();
        assert_eq!(action, format!("{}/lti/launch", lti.tool));
        let page = self.post(&lti.http, &action, &fields).await;
        (action, fields, page)
    }
}

async fn tool_jwks(lti: &Lti) -> Value {
    let r = lti
        .http
        .get(format!("{}/lti/jwks", lti.tool))
        .send()
        .await
        .unwrap();
    r.json().await.unwrap()
}

async fn platform_scores(lti: &Lti) -> Vec<Value> {
    let r = lti
        .http
        .get(format!("{}/debug/scores", lti.platform_url))
        .send()
        .await
        .unwrap();
    r.json::<Vec<Value>>().await.unwrap()
}

async fn wait_for_score(lti: &Lti, progress: &str) -> Value {
    let until = tokio::time::Instant::now() + DELIVERY_LIMIT;
    loop {
        if let Some(s) = platform_scores(lti)
            .await
            .into_iter()
            .find(|s| s["score"]["gradingProgress"] == progress)
        {
            return s["score"].clone();
        }
        if tokio::time::Instant::now() > until {
            let outbox = server::outbox::status(lti.app.pool()).await.unwrap();
            let queued: i64 = sqlx::query_scalar("SELECT count(*) FROM lti_score_queue")
                .fetch_one(lti.app.pool())
                .await
                .unwrap();
            panic!("no {progress} score reached the platform (queue {queued}, outbox {outbox:?})");
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

#[tokio::test]
async fn lti_flow_deep_link_launch_scores_results_and_memberships() {
    // The LTI session is the platform's authentication; TOTP for approval is tested elsewhere.
    let lti = Lti::start(&[("PAINSIM_REQUIRE_TOTP_FOR_APPROVAL", "false")]).await;
    let state = lti.state();
    let outbox = Outbox::new(lti.app.pool().clone());
    spawn_score_pump(state.clone(), outbox.clone(), std::future::pending());
    outbox.spawn(std::future::pending());

    // Deep linking: the instructor chooses a station; the signed response goes back.
    let mut teacher = Browser::default();
    let (_, _, page) = teacher
        .launch(&lti, "message=deeplink&user=teacher-1&role=instructor")
        .await;
    assert_eq!(page.status, 200, "{}", page.text);
    assert!(page.cookie_set("painsim_session"));
    let choice = page
        .text
        .split("<form")
        .find(|f| f.contains(&format!("value=\"{STATION}\"")))
        .map(|f| Page {
            status: 200,
            headers: Default::default(),
            text: format!("<form{f}"),
        })
        .expect("the station is offered");
    let (action, fields) = choice.form();
    let back = teacher
        .post(&lti.http, &format!("{}{action}", lti.tool), &fields)
        .await;
    assert_eq!(back.status, 200, "{}", back.text);
    let csp = back.headers["content-security-policy"].to_str().unwrap();
    assert!(
        csp.contains(&format!("form-action {}", lti.platform_url)),
        "{csp}"
    );
    let (return_url, jwt) = back.form();
    assert_eq!(return_url, format!("{}/deep-link-return", lti.platform_url));
    let linked = teacher.post(&lti.http, &return_url, &jwt).await;
    assert_eq!(
        linked.status, 200,
        "the platform validates the deep-linking response: {}",
        linked.text
    );
    let linked = linked.json();
    assert_eq!(
        linked["data"], "opaque-platform-data-7",
        "the data claim comes back"
    );
    let link = &linked["links"][0];
    assert_eq!(link["item"]["type"], "ltiResourceLink");
    assert_eq!(link["item"]["custom"]["station_id"], STATION);
    assert_eq!(link["lineitem"]["scoreMaximum"], 100);
    let lineitem = link["lineitem"]["id"].as_str().unwrap().to_owned();
    let link_id = link["resource_link_id"].as_str().unwrap().to_owned();

    // The learner's launch lands on the station, with an account, the course and a session.
    let mut learner = Browser::default();
    let (_, _, page) = learner
        .launch(
            &lti,
            &format!("message=resource&user=learner-1&role=learner&link={link_id}"),
        )
        .await;
    assert_eq!(page.status, 200, "{}", page.text);
    assert!(
        page.text.contains(&format!("station={STATION}")),
        "{}",
        page.text
    );
    let session = learner.session();
    let me = lti
        .app
        .send(Method::GET, "/api/auth/me", Some(&session), None)
        .await;
    assert_eq!(me.status, StatusCode::OK, "{}", me.text);
    assert_eq!(me.json["user"]["role"], "learner");
    assert_eq!(me.json["user"]["display_name"], "learner-1");
    let learner_id: Uuid = me.json["user"]["id"].as_str().unwrap().parse().unwrap();
    let courses = lti
        .app
        .send(Method::GET, "/api/courses", Some(&session), None)
        .await;
    let course = courses
        .json
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["title"] == "Interventional pain, spring")
        .expect("the LTI course")
        .clone();
    assert_eq!(course["my_role"], "learner");
    let course_id: Uuid = course["id"].as_str().unwrap().parse().unwrap();

    // Scored: Completed + PendingManual with the technical score.
    let attempt = lti.app.open_attempt(&session, course_id, STATION).await;
    let result = lti
        .app
        .store_result(learner_id, attempt, facet_measurements_met())
        .await
        .expect("a result");
    let given = (result.score.expect("a score") * 100.0 * 100.0).round() / 100.0;
    let pending = wait_for_score(&lti, "PendingManual").await;
    assert_eq!(pending["userId"], "learner-1");
    assert_eq!(pending["activityProgress"], "Completed");
    assert_eq!(pending["scoreGiven"], json!(given));
    assert_eq!(pending["scoreMaximum"], json!(100.0));

    // Approved by the course's (LTI) faculty: FullyGraded.
    let faculty = teacher.session();
    let r = lti
        .app
        .send(
            Method::POST,
            &format!("/api/attempts/{attempt}/review"),
            Some(&faculty),
            Some(json!({ "decision": "approve", "comment": "good" })),
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    let graded = wait_for_score(&lti, "FullyGraded").await;
    assert_eq!(graded["scoreGiven"], json!(given));
    let at = |s: &Value| {
        time::OffsetDateTime::parse(
            s["timestamp"].as_str().unwrap(),
            &time::format_description::well_known::Rfc3339,
        )
        .unwrap()
    };
    assert!(at(&graded) > at(&pending), "timestamps increase");
    assert_eq!(
        platform_scores(&lti).await.len(),
        2,
        "each stage is published once"
    );

    // Read back through the AGS result service (result.readonly).
    let platform = platforms::get(lti.app.pool(), lti.platform_id)
        .await
        .unwrap()
        .unwrap();
    let token = access_token(&state, &platform, SCOPES_AGS)
        .await
        .expect("an access token");
    let results: Value = lti
        .http
        .get(format!("{lineitem}/results"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(
        results,
        json!([{
            "id": format!("{lineitem}/results/learner-1"), "userId": "learner-1", "resultScore": given,
            "resultMaximum": 100.0, "comment": "technical criteria met", "scoreOf": lineitem,
        }])
    );

    // Names and Role Provisioning fills the course (3 pages of 2; one inactive member).
    let r = lti
        .app
        .send(
            Method::POST,
            &format!("/api/lti/courses/{course_id}/memberships/sync"),
            Some(&faculty),
            None,
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    assert_eq!(
        r.json,
        json!({ "members": 4, "accounts_created": 2, "skipped": 1, "pages": 3 })
    );
    let members: i64 =
        sqlx::query_scalar("SELECT count(*) FROM course_members WHERE course_id = $1")
            .bind(course_id)
            .fetch_one(lti.app.pool())
            .await
            .unwrap();
    assert_eq!(members, 4);

    // Key rotation: the new key signs, the old one stays published.
    let before: Value = tool_jwks(&lti).await;
    assert_eq!(before["keys"].as_array().unwrap().len(), 1);
    let r = lti
        .app
        .send(
            Method::POST,
            "/api/admin/lti/keys/rotate",
            Some(&lti.admin),
            None,
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    let after: Value = tool_jwks(&lti).await;
    let kids: Vec<&str> = after["keys"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k["kid"].as_str().unwrap())
        .collect();
    assert_eq!(
        kids,
        [
            r.json["kid"].as_str().unwrap(),
            before["keys"][0]["kid"].as_str().unwrap()
        ]
    );
}

/// A launch the tool must refuse: 401 `lti_launch_refused` whose message says `why`, no session.
async fn refused(query: &str, why: &str) {
    let lti = Lti::start(&[]).await;
    let mut b = Browser::default();
    let (_, _, page) = b.launch(&lti, query).await;
    assert_refused(&page, why).await;
    assert_eq!(lti.sessions().await, 1, "only the admin's session");
}

async fn assert_refused(page: &Page, why: &str) {
    assert_eq!(page.status, 401, "{}", page.text);
    assert_eq!(page.json()["error"]["code"], "lti_launch_refused");
    let msg = page.json()["error"]["message"].as_str().unwrap().to_owned();
    assert!(msg.contains(why), "{msg:?} should say {why:?}");
    assert!(!page.cookie_set("painsim_session"), "no session cookie");
}

#[tokio::test]
async fn lti_rejects_bad_signature() {
    refused(
        "message=resource&user=learner-1&tamper=signature",
        "bad signature",
    )
    .await;
}

#[tokio::test]
async fn lti_rejects_expired_token() {
    refused("message=resource&user=learner-1&tamper=expired", "expired").await;
}

#[tokio::test]
async fn lti_rejects_wrong_audience() {
    refused(
        "message=resource&user=learner-1&tamper=audience",
        "wrong audience",
    )
    .await;
}

#[tokio::test]
async fn lti_rejects_unknown_deployment() {
    refused(
        "message=resource&user=learner-1&tamper=deployment",
        "unknown deployment",
    )
    .await;
}

#[tokio::test]
async fn lti_rejects_replayed_nonce() {
    let lti = Lti::start(&[]).await;
    let mut b = Browser::default();
    let (action, fields, first) = b.launch(&lti, "message=resource&user=learner-1").await;
    assert_eq!(first.status, 200, "{}", first.text);
    assert_eq!(lti.sessions().await, 2, "the admin's and the learner's");
    // The same id_token and state again (an attacker who captured the form post).
    let mut attacker = Browser::default();
    let again = attacker.post(&lti.http, &action, &fields).await;
    assert_refused(&again, "replayed").await;
    assert_eq!(lti.sessions().await, 2, "no new session");
}

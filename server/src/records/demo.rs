//! Demo accounts for the embedded-default run (a local machine with no configuration).
//!
//! They are marked `is_demo` in the database and in every API answer about them, use e-mail
//! addresses under the reserved `.invalid` top-level domain (RFC 2606), and share one published
//! password: they exist to try the platform, never to hold real records. Start-up calls
//! [`ensure_demo_accounts`] only when the embedded database is in use, and prints
//! [`startup_notice`].

use sqlx::PgPool;
use uuid::Uuid;

use super::auth::Role;
use super::config::Argon2Cost;
use super::users::{CreateUserError, create_user};

/// The demo password (published on purpose: demo accounts are not for real records).
pub const DEMO_PASSWORD: &str = "demo-password-not-secret";
/// Code of the demo course.
pub const DEMO_COURSE: &str = "DEMO-101";

/// A demo account.
#[derive(Debug, Clone)]
pub struct DemoAccount {
    /// E-mail.
    pub email: &'static str,
    /// Role.
    pub role: Role,
}

/// The demo accounts: one admin, one faculty and two learners of the demo course.
pub const DEMO_ACCOUNTS: [(&str, &str, Role, Option<&str>); 4] = [
    ("admin@demo.invalid", "Demo Admin", Role::Admin, None),
    (
        "faculty@demo.invalid",
        "Demo Faculty",
        Role::Faculty,
        Some("faculty"),
    ),
    (
        "learner@demo.invalid",
        "Demo Learner",
        Role::Learner,
        Some("learner"),
    ),
    (
        "learner2@demo.invalid",
        "Demo Learner Two",
        Role::Learner,
        Some("learner"),
    ),
];

/// Creates the demo accounts and course if missing (idempotent). Returns the accounts.
pub async fn ensure_demo_accounts(
    pool: &PgPool,
    cost: Argon2Cost,
) -> Result<Vec<DemoAccount>, CreateUserError> {
    sqlx::query("INSERT INTO courses (id, code, title) VALUES ($1, $2, 'Demo course (not real records)') ON CONFLICT (code) DO NOTHING")
        .bind(Uuid::new_v4())
        .bind(DEMO_COURSE)
        .execute(pool)
        .await?;
    let course: Uuid = sqlx::query_scalar("SELECT id FROM courses WHERE code = $1")
        .bind(DEMO_COURSE)
        .fetch_one(pool)
        .await?;
    let mut out = Vec::new();
    for (email, name, role, course_role) in DEMO_ACCOUNTS {
        match create_user(pool, cost, email, name, role, DEMO_PASSWORD, true).await {
            Ok(_) | Err(CreateUserError::EmailTaken(_)) => {}
            Err(e) => return Err(e),
        }
        if let Some(course_role) = course_role {
            sqlx::query(
                "INSERT INTO course_members (course_id, user_id, role) SELECT $1, id, $3 FROM users WHERE email = $2 AND is_demo
                 ON CONFLICT DO NOTHING",
            )
            .bind(course)
            .bind(email)
            .bind(course_role)
            .execute(pool)
            .await?;
        }
        out.push(DemoAccount { email, role });
    }
    Ok(out)
}

/// The start-up message listing the demo accounts.
pub fn startup_notice(accounts: &[DemoAccount]) -> String {
    let mut s = format!(
        "DEMO ACCOUNTS (embedded database only; not for real records) - password for all: {DEMO_PASSWORD}\n"
    );
    for a in accounts {
        s.push_str(&format!("  {:<24} {}\n", a.email, a.role.as_str()));
    }
    s.push_str("  Approving needs TOTP: log in as faculty, POST /api/auth/totp/enroll, confirm, log in again with a code.\n");
    s
}

//! `server create-admin --email ADDRESS`: creates the first admin account.
//!
//! The password is read from `PAINSIM_ADMIN_PASSWORD` if set, else from the first line of
//! standard input; never from the command line, where other users could read it in the process
//! list. The database is the same one `server` would use (`DATABASE_URL`, or the embedded cluster
//! under `PAINSIM_DATA_DIR`), with migrations applied.

use std::io::BufRead;
use std::process::ExitCode;

use crate::config::Config;
use crate::records::users::{CreateUserError, create_admin};

/// Why the arguments of `create-admin` are not understood.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UsageError {
    /// `--email` without its address.
    #[error("--email needs an address")]
    MissingAddress,
    /// Anything else than one `--email` option.
    #[error(
        "usage: server create-admin --email ADDRESS  (password from PAINSIM_ADMIN_PASSWORD or stdin)"
    )]
    Usage,
}

/// Parses `--email ADDRESS` (or `--email=ADDRESS`).
pub fn parse_email(args: &[String]) -> Result<String, UsageError> {
    match args {
        [one] if one.starts_with("--email=") => Ok(one["--email=".len()..].to_owned()),
        [flag, address] if flag == "--email" => Ok(address.clone()),
        [flag] if flag == "--email" => Err(UsageError::MissingAddress),
        _ => Err(UsageError::Usage),
    }
}

/// Runs the command with the arguments after `create-admin`.
pub fn create_admin_main(args: &[String]) -> ExitCode {
    let email = match parse_email(args) {
        Ok(e) => e,
        Err(m) => {
            eprintln!("{m}");
            return ExitCode::from(2);
        }
    };
    let password = match crate::config::admin_password(crate::config::env) {
        Some(p) => p,
        None => {
            eprintln!("password for {email} (one line on standard input):");
            let mut line = String::new();
            if std::io::stdin().lock().read_line(&mut line).is_err() {
                eprintln!("error: cannot read the password from standard input");
                return ExitCode::from(2);
            }
            line.trim_end_matches(['\r', '\n']).to_owned()
        }
    };
    let config = match Config::from_env() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("building the tokio runtime");
    let outcome = runtime.block_on(async {
        let db = crate::startup::open_database(&config).await?;
        let created = create_admin(&db.pool, config.records.argon2, &email, &password).await;
        db.pool.close().await;
        if let Some(c) = db.cluster {
            tokio::task::spawn_blocking(move || c.stop()).await??;
        }
        anyhow::Ok(created)
    });
    match outcome {
        Ok(Ok(user)) => {
            println!("created admin {} ({})", user.email, user.id);
            ExitCode::SUCCESS
        }
        Ok(Err(e @ (CreateUserError::Invalid(_) | CreateUserError::EmailTaken(_)))) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
        Ok(Err(e)) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{UsageError, parse_email};

    #[test]
    fn email_argument_forms() {
        let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
        assert_eq!(parse_email(&s(&["--email", "a@b.c"])).unwrap(), "a@b.c");
        assert_eq!(parse_email(&s(&["--email=a@b.c"])).unwrap(), "a@b.c");
        assert_eq!(parse_email(&s(&[])), Err(UsageError::Usage));
        assert_eq!(
            parse_email(&s(&["--email"])),
            Err(UsageError::MissingAddress)
        );
        assert_eq!(
            parse_email(&s(&["--password", "x"])),
            Err(UsageError::Usage)
        );
    }
}

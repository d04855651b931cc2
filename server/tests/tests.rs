//! Integration tests of the server against a real PostgreSQL, one module per area.

mod anatomy_readiness;
mod dispatch;
mod dispatch_hardening;
mod dispatch_ws_fuzz;
mod e2e_browser;
mod embedded;
mod health;
mod openapi_fuzz;
mod process;
mod records_accounts;
mod records_approval;
mod records_auth;
mod records_authz;
mod records_bad_input;
mod records_demo;
mod records_nul;
mod records_results;
mod records_sigkill;
mod records_support;
mod server_process;
mod security_headers;
mod session_sigkill;
mod xapi_credentials;
mod xapi_documents;
mod xapi_support;

//! The About resource (`GET /xapi/about`): the versions this LRS speaks. Open to everyone, with no
//! version header needed (xAPI 2.0, Communication 2.8).

use axum::Json;
use serde::Serialize;
use serde_json::{Map, Value};
use utoipa::ToSchema;

use super::version::SUPPORTED_VERSIONS;

/// What the LRS says about itself.
#[derive(Debug, Serialize, ToSchema)]
pub struct About {
    /// xAPI versions supported, newest first.
    pub version: Vec<String>,
    /// Extensions (none).
    #[schema(value_type = Object)]
    pub extensions: Map<String, Value>,
}

/// The LRS's versions.
#[utoipa::path(get, path = "/xapi/about", tag = "xapi",
    responses((status = 200, body = About, description = "Supported xAPI versions")))]
pub async fn about() -> Json<About> {
    Json(About {
        version: SUPPORTED_VERSIONS.iter().map(|v| (*v).to_owned()).collect(),
        extensions: Map::new(),
    })
}

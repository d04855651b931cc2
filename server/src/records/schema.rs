//! Hand-built OpenAPI schemas for the constraints utoipa's attributes cannot state: JSON objects
//! without NUL anywhere, the activity kinds a client may send, the review queue's states and the
//! comment a returned attempt needs. Each is built from the same constants the handlers check,
//! so the document cannot drift from the server.
//!
//! Strings in request bodies carry the pattern [`NO_NUL`] (or a stricter one) because
//! [`super::extract::ApiJson`] refuses a NUL in any string or key of a body (PostgreSQL stores
//! none); utoipa takes patterns only as literals, so the attributes repeat the text of
//! [`NO_NUL`] and a unit test checks that they do.

use utoipa::openapi::{KnownFormat, RefOr, SchemaFormat};
use utoipa::openapi::schema::{
    AdditionalProperties, ArrayBuilder, ArrayItems, ObjectBuilder, OneOfBuilder, Schema, SchemaType, Type,
};
use utoipa::{PartialSchema, ToSchema};

use super::activity::ActivityKind;
use super::reviews::{MAX_BULK, MAX_COMMENT_CHARS, ReviewRequest};

/// A string without NUL (ECMA-262 and Python both read `\u0000`).
pub const NO_NUL: &str = "^[^\\u0000]*$";

/// A string without NUL that is not blank after trimming: one character that is neither NUL nor
/// Unicode `White_Space` (what Rust's `str::trim` removes, listed because regex dialects disagree
/// on `\s`).
pub const NOT_BLANK: &str = "^[^\\u0000]*[^\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000][^\\u0000]*$";

/// An e-mail address as accounts store it: one `@` with something on either side, and neither
/// NUL nor `White_Space` anywhere ([`super::users::normalize_email`]).
pub const EMAIL: &str = "^[^@\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000]+@[^@\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000]+$";

fn text(pattern: &str) -> ObjectBuilder {
    ObjectBuilder::new()
        .schema_type(Type::String)
        .pattern(Some(pattern))
}

/// A JSON value whose strings and keys hold no NUL: scalars, and arrays and objects of scalars
/// nested at most `depth` levels.
fn value_without_nul(depth: usize) -> Schema {
    let mut one_of = OneOfBuilder::new()
        .item(text(NO_NUL))
        .item(ObjectBuilder::new().schema_type(Type::Number))
        .item(ObjectBuilder::new().schema_type(Type::Boolean))
        .item(ObjectBuilder::new().schema_type(Type::Null));
    if depth > 0 {
        one_of = one_of
            .item(ArrayBuilder::new().items(ArrayItems::RefOrSchema(Box::new(RefOr::T(
                value_without_nul(depth - 1),
            )))))
            .item(object_without_nul(depth - 1));
    }
    one_of.build().into()
}

/// A JSON object whose keys and nested strings hold no NUL.
fn object_without_nul(depth: usize) -> ObjectBuilder {
    ObjectBuilder::new()
        .schema_type(Type::Object)
        .property_names(Some(text(NO_NUL)))
        .additional_properties(Some(AdditionalProperties::RefOr(RefOr::T(
            value_without_nul(depth),
        ))))
}

/// `detail` of a new activity event: absent, `null` or a JSON object (at most
/// [`super::activity::MAX_ACTIVITY_DETAIL_BYTES`] bytes of JSON, three levels deep here) whose
/// strings and keys hold no NUL.
pub fn activity_detail() -> Schema {
    ObjectBuilder::new()
        .schema_type(SchemaType::from_iter([
            Type::Object,
            Type::Null,
        ]))
        .property_names(Some(text(NO_NUL)))
        .additional_properties(Some(AdditionalProperties::RefOr(RefOr::T(
            value_without_nul(2),
        ))))
        .description(Some(format!(
            "Details (view angles, exposure, volume): a JSON object of at most {} bytes",
            super::activity::MAX_ACTIVITY_DETAIL_BYTES
        )))
        .build()
        .into()
}

/// The activity kinds a client may report (the others are recorded by the server).
pub fn client_activity_kinds() -> Schema {
    ObjectBuilder::new()
        .schema_type(Type::String)
        .enum_values(Some(
            ActivityKind::ALL
                .iter()
                .filter(|k| !k.server_only())
                .map(|k| k.as_str()),
        ))
        .description(Some(
            "What happened; `station_opened` and `submission` are recorded by the server only",
        ))
        .build()
        .into()
}

/// `attempt_ids` of a bulk approval: 1 to [`MAX_BULK`] attempt ids, no repeats.
pub fn bulk_attempt_ids() -> Schema {
    ArrayBuilder::new()
        .items(
            ObjectBuilder::new()
                .schema_type(Type::String)
                .format(Some(SchemaFormat::KnownFormat(KnownFormat::Uuid))),
        )
        .min_items(Some(1))
        .max_items(Some(MAX_BULK))
        .unique_items(true)
        .description(Some("Attempts to approve (no repeats)"))
        .build()
        .into()
}

/// States the review queue filters by.
pub const QUEUE_STATES: [&str; 5] = ["submitted", "returned", "approved", "in_progress", "any"];

/// The review queue's `state` filter.
pub fn queue_state() -> Schema {
    ObjectBuilder::new()
        .schema_type(Type::String)
        .enum_values(Some(QUEUE_STATES))
        .default(Some("submitted".into()))
        .build()
        .into()
}

/// A review: `approve` with an optional comment, or `return` with a comment that is not blank.
/// Comments have at most [`MAX_COMMENT_CHARS`] characters (after trimming).
impl PartialSchema for ReviewRequest {
    fn schema() -> RefOr<Schema> {
        let comment = |pattern: &str| {
            text(pattern)
                .max_length(Some(MAX_COMMENT_CHARS))
                .description(Some("Comment to the learner; required when returning"))
        };
        let decision = |d: &str| {
            ObjectBuilder::new()
                .schema_type(Type::String)
                .enum_values(Some([d]))
        };
        let approve = ObjectBuilder::new()
            .property("decision", decision("approve"))
            .property("comment", comment(NO_NUL))
            .required("decision")
            .additional_properties(Some(AdditionalProperties::FreeForm(false)));
        let ret = ObjectBuilder::new()
            .property("decision", decision("return"))
            .property("comment", comment(NOT_BLANK))
            .required("decision")
            .required("comment")
            .additional_properties(Some(AdditionalProperties::FreeForm(false)));
        RefOr::T(
            OneOfBuilder::new()
                .item(approve)
                .item(ret)
                .description(Some("A review to record: approve, or return with a comment"))
                .build()
                .into(),
        )
    }
}

impl ToSchema for ReviewRequest {}

#[cfg(test)]
mod tests {
    use super::*;

    /// The literal patterns in `#[schema(pattern = ...)]` attributes equal these constants.
    #[test]
    fn attribute_patterns_repeat_the_constants() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src/records");
        let mut seen = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let text = std::fs::read_to_string(entry.unwrap().path()).unwrap();
            for (i, _) in text.match_indices("pattern = \"") {
                let rest = &text[i + "pattern = \"".len()..];
                let lit = &rest[..rest.find("\")").or_else(|| rest.find("\",")).unwrap()];
                let value = lit.replace("\\\\", "\\");
                if value.contains("u0000") {
                    assert!([NO_NUL, NOT_BLANK, EMAIL].contains(&value.as_str()), "{value}");
                    seen += 1;
                }
            }
        }
        assert!(seen > 5, "only {seen} patterns found");
    }
}

//! The route table of the HTTP API and the parsing of request paths and query strings: what the
//! server answers, kept apart from how it answers (the handlers in `api.rs`).

use super::api::ApiError;

/// What a route does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Handler {
    Health,
    OpenApi,
    Submit,
    List,
    Get,
    Cancel,
    Resume,
    Events,
    Outputs,
    Output,
    Upload,
}

/// One route: method, path pattern (`{name}` matches one path segment) and handler.
pub struct Route {
    pub method: &'static str,
    pub path: &'static str,
    pub handler: Handler,
}

/// Every route the server answers.
pub const ROUTES: &[Route] = &[
    Route { method: "GET", path: "/v1/health", handler: Handler::Health },
    Route { method: "GET", path: "/v1/openapi.json", handler: Handler::OpenApi },
    Route { method: "POST", path: "/v1/jobs", handler: Handler::Submit },
    Route { method: "GET", path: "/v1/jobs", handler: Handler::List },
    Route { method: "GET", path: "/v1/jobs/{id}", handler: Handler::Get },
    Route { method: "DELETE", path: "/v1/jobs/{id}", handler: Handler::Cancel },
    Route { method: "POST", path: "/v1/jobs/{id}/resume", handler: Handler::Resume },
    Route { method: "GET", path: "/v1/jobs/{id}/events", handler: Handler::Events },
    Route { method: "GET", path: "/v1/jobs/{id}/outputs", handler: Handler::Outputs },
    Route { method: "GET", path: "/v1/jobs/{id}/outputs/{name}", handler: Handler::Output },
    Route { method: "PUT", path: "/v1/volumes/{name}", handler: Handler::Upload },
];

/// The route for `method` and `path`, and the values of its `{…}` segments.
pub fn route(method: &str, path: &str) -> Result<(Handler, Vec<String>), ApiError> {
    let segments: Vec<&str> = path.trim_end_matches('/').split('/').collect();
    let mut path_known = false;
    for r in ROUTES {
        let pattern: Vec<&str> = r.path.split('/').collect();
        if pattern.len() != segments.len() {
            continue;
        }
        let mut params = Vec::new();
        let matched = pattern.iter().zip(&segments).all(|(p, s)| {
            if p.starts_with('{') {
                params.push(percent_decode(s));
                !s.is_empty()
            } else {
                p == s
            }
        });
        if matched {
            path_known = true;
            if r.method == method {
                return Ok((r.handler, params));
            }
        }
    }
    if path_known {
        Err(ApiError::MethodNotAllowed { method: method.to_string(), path: path.to_string() })
    } else {
        Err(ApiError::NotFound(format!("no such endpoint: {path}")))
    }
}

fn percent_decode(s: &str) -> String {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            if let Some(b) = std::str::from_utf8(&bytes[i + 1..i + 3]).ok().and_then(|h| u8::from_str_radix(h, 16).ok())
            {
                out.push(b);
                i += 3;
                continue;
            }
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// A request's query string.
pub struct Query<'a>(pub(super) &'a str);

impl Query<'_> {
    pub(super) fn get(&self, key: &str) -> Option<String> {
        self.0
            .split('&')
            .filter_map(|kv| kv.split_once('=').or(Some((kv, ""))))
            .find(|(k, _)| *k == key)
            .map(|(_, v)| percent_decode(v))
    }

    pub(super) fn parse<T: std::str::FromStr>(&self, key: &str) -> Result<Option<T>, ApiError> {
        self.get(key)
            .map(|v| v.parse().map_err(|_| ApiError::BadRequest(format!("query parameter {key}: cannot parse {v:?}"))))
            .transpose()
    }

    pub(super) fn flag(&self, key: &str) -> Result<bool, ApiError> {
        match self.get(key).as_deref() {
            None | Some("false") | Some("0") => Ok(false),
            Some("") | Some("true") | Some("1") => Ok(true),
            Some(v) => Err(ApiError::BadRequest(format!("query parameter {key}: expected true or false, got {v:?}"))),
        }
    }
}

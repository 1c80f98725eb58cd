//! `openapi.yaml` and the router describe the same API: every route the server serves is in the
//! spec and every operation of the spec is served, every operation documents its errors with the
//! shared error body, and every `$ref` of the document resolves. And the contract works for
//! generated clients: a default error response everywhere, media types they read, no frozen
//! request defaults, conditional requests declared, `rr` typed with the tracer's own grammar
//! (`tests/generated_client.rs` drives a whole job with a generated client).

use serde_json::Value;
use std::collections::BTreeSet;

/// The HTTP methods an OpenAPI path item may hold an operation under.
const METHODS: [&str; 8] = [
    "get", "put", "post", "delete", "options", "head", "patch", "trace",
];

const ERROR_BODY: &str = "#/components/schemas/ErrorBody";

/// Paths whose operations report failure with 503 (and declare no 4xx).
const HEALTH_PATHS: [&str; 2] = ["/healthz", "/readyz"];

fn spec() -> Value {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../openapi.yaml");
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("cannot read {path}: {e}"));
    serde_norway::from_str(&text).unwrap_or_else(|e| panic!("{path} is not valid YAML: {e}"))
}

/// One operation of the spec.
struct Operation<'a> {
    method: String,
    path: &'a str,
    path_item: &'a Value,
    op: &'a Value,
}

impl Operation<'_> {
    fn name(&self) -> String {
        format!("{} {}", self.method, self.path)
    }
}

fn operations(spec: &Value) -> Vec<Operation<'_>> {
    let paths = spec["paths"]
        .as_object()
        .expect("openapi.yaml has a `paths` object");
    let mut out = Vec::new();
    for (path, item) in paths {
        let item_obj = item
            .as_object()
            .unwrap_or_else(|| panic!("path item {path} is not an object"));
        assert!(
            !item_obj.contains_key("$ref"),
            "path item {path} is a $ref; write its operations inline so they can be checked"
        );
        for (key, op) in item_obj {
            if METHODS.contains(&key.as_str()) {
                out.push(Operation {
                    method: key.to_ascii_uppercase(),
                    path,
                    path_item: item,
                    op,
                });
            }
        }
    }
    out
}

/// Follows a local `$ref` (one level at a time, until the value is not a reference).
fn resolve<'a>(spec: &'a Value, mut v: &'a Value) -> &'a Value {
    for _ in 0..16 {
        let Some(r) = v.get("$ref").and_then(Value::as_str) else {
            return v;
        };
        let pointer = r
            .strip_prefix('#')
            .unwrap_or_else(|| panic!("$ref {r:?} is not local"));
        v = spec
            .pointer(pointer)
            .unwrap_or_else(|| panic!("$ref {r:?} does not resolve"));
    }
    panic!("$ref chain too long (a cycle?)");
}

fn is_error_body(spec: &Value, response: &Value) -> bool {
    resolve(spec, response)
        .pointer("/content/application~1json/schema/$ref")
        .and_then(Value::as_str)
        == Some(ERROR_BODY)
}

#[test]
fn router_and_spec_have_the_same_routes() {
    let spec = spec();
    let documented: Vec<(String, String)> = operations(&spec)
        .iter()
        .map(|o| (o.method.clone(), o.path.to_string()))
        .collect();
    let served: Vec<(String, String)> = pathfarm_server::routes::api_routes()
        .iter()
        .map(|r| (r.method.as_str().to_string(), r.path.to_string()))
        .collect();
    let documented_set: BTreeSet<_> = documented.iter().cloned().collect();
    let served_set: BTreeSet<_> = served.iter().cloned().collect();
    assert_eq!(
        served.len(),
        served_set.len(),
        "api_routes() lists a route twice"
    );

    let fmt = |set: Vec<&(String, String)>| {
        set.iter()
            .map(|(m, p)| format!("\n  {m} {p}"))
            .collect::<String>()
    };
    let undocumented: Vec<_> = served_set.difference(&documented_set).collect();
    let unserved: Vec<_> = documented_set.difference(&served_set).collect();
    assert!(
        undocumented.is_empty() && unserved.is_empty(),
        "openapi.yaml and api_routes() disagree.\nServed but not in openapi.yaml:{}\nIn openapi.yaml but not served:{}",
        if undocumented.is_empty() { "\n  (none)".into() } else { fmt(undocumented) },
        if unserved.is_empty() { "\n  (none)".into() } else { fmt(unserved) },
    );
    assert!(!served.is_empty());
}

#[test]
fn every_operation_documents_its_errors_with_the_error_body() {
    let spec = spec();
    let mut problems = Vec::new();
    for o in operations(&spec) {
        let Some(responses) = o.op["responses"].as_object() else {
            problems.push(format!("{}: no responses", o.name()));
            continue;
        };
        // Every error the server produces is an ErrorBody, so every documented 4xx and 5xx that
        // has a JSON body must say so.
        for (status, response) in responses {
            let is_error = status.starts_with('4') || status.starts_with('5');
            let has_json = resolve(&spec, response)
                .pointer("/content/application~1json")
                .is_some();
            if is_error && has_json && !is_error_body(&spec, response) {
                problems.push(format!(
                    "{}: {status} has a JSON body that is not {ERROR_BODY}",
                    o.name()
                ));
            }
        }
        if HEALTH_PATHS.contains(&o.path) {
            if !responses
                .get("503")
                .is_some_and(|r| is_error_body(&spec, r))
            {
                problems.push(format!("{}: no 503 response with {ERROR_BODY}", o.name()));
            }
        } else if !responses
            .iter()
            .any(|(status, r)| status.starts_with('4') && is_error_body(&spec, r))
        {
            problems.push(format!("{}: no 4xx response with {ERROR_BODY}", o.name()));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn every_ref_resolves_to_a_component() {
    fn walk(spec: &Value, v: &Value, at: &str, problems: &mut Vec<String>, count: &mut usize) {
        match v {
            Value::Object(map) => {
                if let Some(r) = map.get("$ref") {
                    *count += 1;
                    match r.as_str() {
                        Some(r) if r.starts_with("#/components/") => {
                            if spec.pointer(&r[1..]).is_none() {
                                problems.push(format!("{at}: $ref {r:?} does not resolve"));
                            }
                        }
                        _ => problems
                            .push(format!("{at}: $ref {r} does not point into #/components/")),
                    }
                }
                for (k, child) in map {
                    let k = k.replace('~', "~0").replace('/', "~1");
                    walk(spec, child, &format!("{at}/{k}"), problems, count);
                }
            }
            Value::Array(items) => {
                for (i, child) in items.iter().enumerate() {
                    walk(spec, child, &format!("{at}/{i}"), problems, count);
                }
            }
            _ => {}
        }
    }
    let spec = spec();
    let mut problems = Vec::new();
    let mut count = 0;
    walk(&spec, &spec, "#", &mut problems, &mut count);
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    assert!(count > 0, "no $ref found: is this the right file?");
}

#[test]
fn operations_are_well_formed() {
    let spec = spec();
    assert!(
        spec["openapi"]
            .as_str()
            .is_some_and(|v| v.starts_with("3.1.")),
        "openapi.yaml must declare OpenAPI 3.1.x, not {}",
        spec["openapi"]
    );
    assert!(
        spec.pointer("/components/securitySchemes/bearer").is_some(),
        "no bearer security scheme"
    );
    let mut problems = Vec::new();
    let mut ids = BTreeSet::new();
    for o in operations(&spec) {
        match o.op["operationId"].as_str() {
            Some(id) if !ids.insert(id.to_string()) => {
                problems.push(format!("{}: operationId {id} is used twice", o.name()))
            }
            Some(_) => {}
            None => problems.push(format!("{}: no operationId", o.name())),
        }
        // Every `{name}` of the path template is declared as a required path parameter, and no
        // other path parameter is.
        let templated: BTreeSet<&str> = o
            .path
            .split('/')
            .filter_map(|seg| seg.strip_prefix('{')?.strip_suffix('}'))
            .collect();
        let mut declared = BTreeSet::new();
        for params in [&o.path_item["parameters"], &o.op["parameters"]] {
            for p in params.as_array().into_iter().flatten() {
                let p = resolve(&spec, p);
                if p["in"] == "path" {
                    let name = p["name"].as_str().unwrap_or_default();
                    if p["required"] != true {
                        problems.push(format!(
                            "{}: path parameter {name} is not required",
                            o.name()
                        ));
                    }
                    declared.insert(name);
                }
            }
        }
        if templated != declared {
            problems.push(format!(
                "{}: path parameters {declared:?} do not match the template's {templated:?}",
                o.name()
            ));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The media types `openapi-python-client` (and most generators) read: JSON, bytes, text.
fn generators_read(media_type: &str) -> bool {
    media_type == "application/json"
        || media_type == "application/octet-stream"
        || media_type.starts_with("text/")
}

#[test]
fn every_operation_has_a_default_error_response() {
    let spec = spec();
    let mut problems = Vec::new();
    for o in operations(&spec) {
        match o.op["responses"].get("default") {
            Some(r) if is_error_body(&spec, r) => {}
            Some(_) => problems.push(format!("{}: default is not {ERROR_BODY}", o.name())),
            None => problems.push(format!("{}: no default response", o.name())),
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn every_body_has_a_media_type_generators_read() {
    let spec = spec();
    let mut problems = Vec::new();
    for o in operations(&spec) {
        // A request body: generators send one media type, and skip the operation when any
        // listed one is unknown to them; multipart forms they build themselves.
        let body = resolve(&spec, &o.op["requestBody"]);
        for media_type in body["content"]
            .as_object()
            .into_iter()
            .flatten()
            .map(|c| c.0)
        {
            if !(generators_read(media_type) || media_type == "multipart/form-data") {
                problems.push(format!("{}: request body {media_type}", o.name()));
            }
        }
        // A response: generators take the first listed type they read.
        for (status, r) in o.op["responses"].as_object().into_iter().flatten() {
            let Some(content) = resolve(&spec, r)["content"].as_object() else {
                continue;
            };
            if !content.keys().any(|t| generators_read(t)) {
                problems.push(format!(
                    "{} {status}: only {:?}",
                    o.name(),
                    content.keys().collect::<Vec<_>>()
                ));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn request_defaults_are_stated_not_frozen() {
    // A `default` keyword is copied into generated clients, which then send it: a server default
    // that changes would not reach them. Only the `default` response (a status) and the server
    // URL's variables may say `default`.
    fn walk(v: &Value, at: &str, problems: &mut Vec<String>) {
        match v {
            Value::Object(map) => {
                let responses = at.ends_with("/responses");
                let variable = at.contains("/servers/") && at.contains("/variables/");
                if map.contains_key("default") && !responses && !variable {
                    problems.push(format!("{at}: default {}", map["default"]));
                }
                for (k, child) in map {
                    walk(child, &format!("{at}/{k}"), problems);
                }
            }
            Value::Array(items) => {
                for (i, child) in items.iter().enumerate() {
                    walk(child, &format!("{at}/{i}"), problems);
                }
            }
            _ => {}
        }
    }
    let spec = spec();
    let mut problems = Vec::new();
    walk(&spec, "#", &mut problems);
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn every_validated_download_declares_its_conditional_request() {
    let spec = spec();
    let mut problems = Vec::new();
    let mut validated = 0;
    for o in operations(&spec) {
        let ok = resolve(&spec, &o.op["responses"]["200"]);
        if ok.pointer("/headers/ETag").is_none() {
            continue;
        }
        validated += 1;
        let declares = [&o.path_item["parameters"], &o.op["parameters"]]
            .into_iter()
            .flat_map(|p| p.as_array().into_iter().flatten())
            .map(|p| resolve(&spec, p))
            .any(|p| p["in"] == "header" && p["name"] == "If-None-Match");
        if !declares {
            problems.push(format!("{}: an ETag but no If-None-Match", o.name()));
        }
        if o.op["responses"].get("304").is_none() {
            problems.push(format!("{}: an ETag but no 304", o.name()));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    assert_eq!(validated, 2, "image.exr and preview.png carry ETags");
}

#[test]
fn the_roulette_patterns_are_the_tracers_grammar() {
    use pathfarm_tracer::settings::roulette_numbers::{FRACTION, PROBABILITY, THRESHOLD};
    let spec = spec();
    let rr = &spec["components"]["schemas"]["JobSettings"]["properties"]["rr"];
    let branches = rr["anyOf"].as_array().expect("rr is anyOf");
    assert!(
        branches.iter().all(|b| b["type"] == "string"),
        "every branch of rr is typed: {rr}"
    );
    let patterns: Vec<&str> = branches
        .iter()
        .filter_map(|b| b["pattern"].as_str())
        .collect();
    assert_eq!(
        patterns,
        [
            format!("^({PROBABILITY})$"),
            format!("^({FRACTION})@({THRESHOLD})$")
        ],
        "the rr patterns must be the tracer's (settings::roulette_numbers)"
    );
}

#[test]
fn the_worker_cursor_pattern_is_the_servers() {
    let spec = spec();
    let params = spec["paths"]["/api/v1/workers"]["get"]["parameters"]
        .as_array()
        .expect("listWorkers has parameters");
    let after = params
        .iter()
        .find(|p| p["name"] == "after")
        .expect("an `after` parameter");
    assert_eq!(
        after["schema"]["pattern"].as_str(),
        Some(pathfarm_server::store::WorkerCursor::PATTERN),
        "the contract's cursor pattern must be the one the server reads"
    );
}

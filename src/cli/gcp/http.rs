//! The least HTTP/1.1 the picking page needs: one request a connection, bodies by
//! Content-Length, and the checks that keep other sites and other machines out.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::time::Duration;

/// Longest header block and body accepted: the page's saves are a few kB per pick.
const MAX_HEADER_BYTES: usize = 64 * 1024;
const MAX_BODY_BYTES: usize = 16 * 1024 * 1024;

pub struct Request {
    pub method: String,
    pub path: String,
    pub host: Option<String>,
    pub origin: Option<String>,
    /// `Sec-Fetch-Site`, which browsers send on every request.
    pub fetch_site: Option<String>,
    pub body: Vec<u8>,
}

pub struct Response {
    pub status: u16,
    pub content_type: &'static str,
    pub body: Vec<u8>,
}

impl Response {
    pub fn json(status: u16, value: &serde_json::Value) -> Response {
        Response {
            status,
            content_type: "application/json",
            body: value.to_string().into_bytes(),
        }
    }

    pub fn error(status: u16, message: impl Into<String>) -> Response {
        Response::json(status, &serde_json::json!({ "error": message.into() }))
    }
}

fn reason(status: u16) -> &'static str {
    match status {
        200 => "OK",
        400 => "Bad Request",
        403 => "Forbidden",
        404 => "Not Found",
        405 => "Method Not Allowed",
        409 => "Conflict",
        413 => "Payload Too Large",
        _ => "Internal Server Error",
    }
}

/// Reads one request; `Err` carries the status and message to answer with.
pub fn read_request(stream: &TcpStream) -> Result<Request, (u16, String)> {
    let _ = stream.set_read_timeout(Some(Duration::from_secs(10)));
    let mut reader = BufReader::new(stream);
    let mut head = Vec::new();
    let mut lines = Vec::new();
    loop {
        let mut line = Vec::new();
        let n = reader
            .read_until(b'\n', &mut line)
            .map_err(|e| (400, format!("reading the request: {e}")))?;
        if n == 0 {
            return Err((400, "the request ended inside its headers".into()));
        }
        head.extend_from_slice(&line);
        if head.len() > MAX_HEADER_BYTES {
            return Err((413, "headers over 64 kB".into()));
        }
        let text = String::from_utf8_lossy(&line).trim_end().to_string();
        if text.is_empty() {
            break;
        }
        lines.push(text);
    }
    let first = lines.first().ok_or((400, "an empty request".to_string()))?;
    let mut parts = first.split_whitespace();
    let (Some(method), Some(path)) = (parts.next(), parts.next()) else {
        return Err((400, format!("not an HTTP request line: '{first}'")));
    };
    let mut req = Request {
        method: method.to_string(),
        path: path.to_string(),
        host: None,
        origin: None,
        fetch_site: None,
        body: Vec::new(),
    };
    let mut length = 0usize;
    for l in &lines[1..] {
        let Some((k, v)) = l.split_once(':') else {
            continue;
        };
        let v = v.trim().to_string();
        match k.trim().to_ascii_lowercase().as_str() {
            "host" => req.host = Some(v),
            "origin" => req.origin = Some(v),
            "sec-fetch-site" => req.fetch_site = Some(v),
            "content-length" => {
                length = v
                    .parse()
                    .map_err(|_| (400, format!("Content-Length '{v}' is not a number")))?;
            }
            "transfer-encoding" => return Err((400, "chunked bodies are not accepted".into())),
            _ => {}
        }
    }
    if length > MAX_BODY_BYTES {
        return Err((413, "a body over 16 MB".into()));
    }
    req.body = vec![0; length];
    reader
        .read_exact(&mut req.body)
        .map_err(|e| (400, format!("reading the body: {e}")))?;
    Ok(req)
}

/// Why a request does not come from the page this server gave out, if it does not: its Host
/// must name this server on the loopback address (a DNS-rebinding page sends its own name), and
/// an Origin, when sent, must be this server's.
pub fn foreign(req: &Request, port: u16) -> Option<String> {
    let ours = [format!("127.0.0.1:{port}"), format!("localhost:{port}")];
    match &req.host {
        None => return Some("no Host header".into()),
        Some(h) if !ours.iter().any(|o| o.eq_ignore_ascii_case(h)) => {
            return Some(format!("Host '{h}' is not this server ({})", ours[0]));
        }
        _ => {}
    }
    if let Some(o) = &req.origin
        && !ours
            .iter()
            .any(|x| format!("http://{x}").eq_ignore_ascii_case(o))
    {
        return Some(format!("Origin '{o}' is not this page"));
    }
    if req
        .fetch_site
        .as_deref()
        .is_some_and(|s| s.eq_ignore_ascii_case("cross-site"))
    {
        return Some("a request from another site".into());
    }
    None
}

pub fn write_response(mut stream: &TcpStream, r: &Response) {
    let head = format!(
        "HTTP/1.1 {} {}\r\nContent-Type: {}\r\nContent-Length: {}\r\nCache-Control: no-store\r\n\
         X-Content-Type-Options: nosniff\r\nX-Frame-Options: DENY\r\nConnection: close\r\n\r\n",
        r.status,
        reason(r.status),
        r.content_type,
        r.body.len()
    );
    // A browser that went away is no reason to stop serving.
    let _ = stream
        .write_all(head.as_bytes())
        .and_then(|()| stream.write_all(&r.body))
        .and_then(|()| stream.flush());
}

//! Finding places in a scene file's text, for errors found after parsing (unknown material names,
//! shapes that cannot be lowered, invalid settings): the parser itself already reports syntax
//! and value errors. A small RON lexer (strings, nested comments, brackets) keeps comments and
//! string contents from being mistaken for fields.

/// A 1-based line and column.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Place {
    /// Line, from 1.
    pub line: usize,
    /// Column in characters, from 1.
    pub column: usize,
}

/// The line and column of a byte offset.
pub fn place_of(source: &str, offset: usize) -> Place {
    let mut offset = offset.min(source.len());
    while !source.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &source[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map(|i| i + 1).unwrap_or(0);
    Place {
        line,
        column: source[line_start..offset].chars().count() + 1,
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Ident,
    Str,
    Open,
    Close,
    Colon,
    Comma,
    Other,
}

#[derive(Debug, Clone, Copy)]
struct Token {
    kind: Kind,
    start: usize,
    end: usize,
}

/// The byte offset of a 1-based line and column (in characters) of `text`, clamped to its end:
/// the inverse of [`place_of`] for the places RON's errors report.
pub fn offset_of(text: &str, place: ron::error::Position) -> usize {
    let mut offset = 0;
    for (i, line) in text.split_inclusive('\n').enumerate() {
        if i + 1 == place.line {
            let column = place.col.saturating_sub(1);
            return offset
                + line
                    .char_indices()
                    .nth(column)
                    .map_or(line.len(), |(b, _)| b);
        }
        offset += line.len();
    }
    text.len()
}

/// Splits RON text into tokens, dropping whitespace and (nested) comments.
fn tokens(source: &str) -> Vec<Token> {
    let bytes = source.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let c = bytes[i];
        let start = i;
        let kind = match c {
            b'/' if bytes.get(i + 1) == Some(&b'/') => {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
                continue;
            }
            b'/' if bytes.get(i + 1) == Some(&b'*') => {
                let mut depth = 0;
                while i < bytes.len() {
                    if bytes[i] == b'/' && bytes.get(i + 1) == Some(&b'*') {
                        depth += 1;
                        i += 2;
                    } else if bytes[i] == b'*' && bytes.get(i + 1) == Some(&b'/') {
                        depth -= 1;
                        i += 2;
                        if depth == 0 {
                            break;
                        }
                    } else {
                        i += 1;
                    }
                }
                continue;
            }
            b'"' => {
                i += 1;
                while i < bytes.len() && bytes[i] != b'"' {
                    i += if bytes[i] == b'\\' { 2 } else { 1 };
                }
                i += 1;
                Kind::Str
            }
            b'(' | b'[' | b'{' => {
                i += 1;
                Kind::Open
            }
            b')' | b']' | b'}' => {
                i += 1;
                Kind::Close
            }
            b':' => {
                i += 1;
                Kind::Colon
            }
            b',' => {
                i += 1;
                Kind::Comma
            }
            c if c.is_ascii_alphabetic() || c == b'_' => {
                while i < bytes.len() && (bytes[i].is_ascii_alphanumeric() || bytes[i] == b'_') {
                    i += 1;
                }
                Kind::Ident
            }
            c if c.is_ascii_whitespace() => {
                i += 1;
                continue;
            }
            c if c.is_ascii_digit() || matches!(c, b'.' | b'+' | b'-') => {
                // a number (`-1.5e-3`, `0x10`) as one token: a file of many objects is mostly
                // numbers, and a token per character made its token list 24 bytes per byte
                while i < bytes.len()
                    && (bytes[i].is_ascii_alphanumeric()
                        || matches!(bytes[i], b'.' | b'+' | b'-' | b'_'))
                {
                    i += 1;
                }
                Kind::Other
            }
            _ => {
                // any other character (UTF-8 continuation bytes included)
                i += 1;
                while i < bytes.len() && !source.is_char_boundary(i) {
                    i += 1;
                }
                Kind::Other
            }
        };
        out.push(Token {
            kind,
            start,
            end: i.min(bytes.len()),
        });
    }
    out
}

/// Offset of the value of the field reached by the key path (e.g. `["image", "samples"]`), where each key
/// is a `name:` (or a map's `"name":`) one bracket level below the previous one, starting inside the top-level
/// `Scene( … )`. `None` when the file does not spell the field out (it took its default).
pub fn field(source: &str, path: &[&str]) -> Option<usize> {
    field_in(source, &tokens(source), path)
}

/// [`field`] over the tokens of `source`.
fn field_in(source: &str, toks: &[Token], path: &[&str]) -> Option<usize> {
    let mut depth = 0usize;
    let mut keys: Vec<Option<&str>> = vec![None];
    for (i, t) in toks.iter().enumerate() {
        match t.kind {
            Kind::Open => {
                depth += 1;
                keys.truncate(depth);
                keys.push(None);
            }
            Kind::Close => {
                depth = depth.saturating_sub(1);
                keys.truncate(depth + 1);
            }
            // A struct field `name:` or a map key `"name":` (compared without its quotes).
            Kind::Ident | Kind::Str if toks.get(i + 1).map(|n| n.kind) == Some(Kind::Colon) => {
                let text = &source[t.start..t.end];
                let name = match t.kind {
                    Kind::Str => text.trim_start_matches('"').trim_end_matches('"'),
                    _ => text,
                };
                keys[depth] = Some(name);
                if depth == path.len()
                    && (1..=path.len()).all(|d| keys.get(d).copied().flatten() == Some(path[d - 1]))
                {
                    return Some(toks.get(i + 2).map_or(t.start, |v| v.start));
                }
            }
            _ => {}
        }
    }
    None
}

/// Byte ranges of the elements of the top-level list field `name` (e.g. `objects`).
pub fn list_elements(source: &str, name: &str) -> Vec<(usize, usize)> {
    let toks = tokens(source);
    let Some(value) = field_in(source, &toks, &[name]) else {
        return Vec::new();
    };
    let Some(open) = toks.iter().position(|t| t.start == value) else {
        return Vec::new();
    };
    if toks.get(open).map(|t| (t.kind, &source[t.start..t.end])) != Some((Kind::Open, "[")) {
        return Vec::new();
    }
    let mut depth = 0usize;
    let mut elements = Vec::new();
    let mut start: Option<usize> = None;
    let mut last_end = toks[open].end;
    for t in &toks[open + 1..] {
        match t.kind {
            Kind::Close if depth == 0 => {
                if let Some(s) = start.take() {
                    elements.push((s, last_end));
                }
                return elements;
            }
            Kind::Comma if depth == 0 => {
                if let Some(s) = start.take() {
                    elements.push((s, last_end));
                }
            }
            _ => {
                start.get_or_insert(t.start);
                match t.kind {
                    Kind::Open => depth += 1,
                    Kind::Close => depth -= 1,
                    _ => {}
                }
            }
        }
        last_end = t.end;
    }
    elements
}

/// One step into a nested value, mirroring [`crate::sdf::lower::Step`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Nav<'a> {
    /// The current value is a node of this kind.
    Node(&'a str),
    /// The named field of the current struct or node.
    Field(&'a str),
    /// The i-th element of the current list (or of a node whose argument is a list).
    Index(usize),
}

/// Follows `steps` from the value that starts at byte `start` (e.g. an element of `objects`)
/// and returns the offset of the value reached, or of the deepest one that could be found.
pub fn follow(source: &str, start: usize, steps: &[Nav]) -> usize {
    let toks = tokens(source);
    let Some(mut cur) = toks.iter().position(|t| t.start >= start) else {
        return start;
    };
    let text = |i: usize| toks.get(i).map(|t| &source[t.start..t.end]);
    let kind = |i: usize| toks.get(i).map(|t| t.kind);
    for step in steps {
        let next = match *step {
            Nav::Node(k) => (text(cur) == Some(k)).then_some(cur),
            Nav::Field(f) => {
                let open = match kind(cur) {
                    Some(Kind::Ident) if kind(cur + 1) == Some(Kind::Open) => Some(cur + 1),
                    Some(Kind::Open) => Some(cur),
                    _ => None,
                };
                open.and_then(|open| {
                    let mut depth = 0i32;
                    let mut i = open + 1;
                    while let Some(t) = toks.get(i) {
                        match t.kind {
                            Kind::Open => depth += 1,
                            Kind::Close if depth == 0 => return None,
                            Kind::Close => depth -= 1,
                            Kind::Ident
                                if depth == 0
                                    && kind(i + 1) == Some(Kind::Colon)
                                    && text(i) == Some(f) =>
                            {
                                return Some(i + 2);
                            }
                            _ => {}
                        }
                        i += 1;
                    }
                    None
                })
            }
            Nav::Index(n) => {
                let list = match (text(cur), kind(cur + 1), text(cur + 2)) {
                    (Some("["), _, _) => Some(cur),
                    (_, Some(Kind::Open), Some("[")) if kind(cur) == Some(Kind::Ident) => {
                        Some(cur + 2)
                    }
                    _ => None,
                };
                list.and_then(|list| {
                    let (mut depth, mut index, mut i) = (0i32, 0usize, list + 1);
                    let mut at_start = true;
                    while let Some(t) = toks.get(i) {
                        match t.kind {
                            Kind::Close if depth == 0 => return None,
                            Kind::Comma if depth == 0 => {
                                index += 1;
                                at_start = true;
                            }
                            _ => {
                                if at_start && depth == 0 && index == n {
                                    return Some(i);
                                }
                                at_start = false;
                                match t.kind {
                                    Kind::Open => depth += 1,
                                    Kind::Close => depth -= 1,
                                    _ => {}
                                }
                            }
                        }
                        i += 1;
                    }
                    None
                })
            }
        };
        match next {
            Some(n) if n < toks.len() => cur = n,
            _ => break,
        }
    }
    toks[cur].start
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offset_of_inverts_place_of() {
        let text = "(\n  color: (1, 0, 0),\n  «x»: ü,\n)";
        for offset in text.char_indices().map(|(b, _)| b) {
            let p = place_of(text, offset);
            let back = offset_of(
                text,
                ron::error::Position {
                    line: p.line,
                    col: p.column,
                },
            );
            assert_eq!(back, offset, "{p:?}");
        }
    }

    #[test]
    fn finds_map_values_by_quoted_key() {
        let src =
            "Scene(\n  materials: {\n    \"red\": (color: (1, 0, 0)),\n    \"b\": Pbr(),\n  },\n)";
        let at = field(src, &["materials", "b"]).unwrap();
        assert!(src[at..].starts_with("Pbr()"));
    }

    #[test]
    fn finds_object_elements() {
        let src = "Scene(\n  camera: X,\n  objects: [\n    (shape: Sphere(radius: 1)), // c\n    (name: \"a,b\", shape: Box(half_extents: (1,1,1))),\n  ],\n)";
        let e = list_elements(src, "objects");
        assert_eq!(e.len(), 2);
        assert!(src[e[0].0..e[0].1].starts_with("(shape: Sphere"));
        assert!(src[e[1].0..e[1].1].starts_with("(name: \"a,b\""));
        assert_eq!(place_of(src, e[1].0), Place { line: 5, column: 5 });
        let shape = follow(src, e[1].0, &[Nav::Field("shape"), Nav::Node("Box")]);
        assert_eq!(place_of(src, shape).line, 5);
    }

    #[test]
    fn fields_ignore_comments_and_strings() {
        let src = "// samples: 3\nScene(\n  /* image: ( /* nested */ samples: 9) */\n  objects: [(name: \"image: samples: \")],\n  image: (\n    width: 4,\n    samples: 0,\n  ),\n)";
        let at = field(src, &["image", "samples"]).unwrap();
        assert_eq!(place_of(src, at).line, 7);
        assert_eq!(place_of(src, field(src, &["image"]).unwrap()).line, 5);
        assert_eq!(field(src, &["samples"]), None);
    }

    #[test]
    fn follows_paths_into_nested_nodes() {
        let src = "(shape: Union([\n  Torus(major: 1, minor: 0.2),\n  Torus(major: 0.5,\n   minor: 1),\n]))";
        let at = follow(
            src,
            0,
            &[
                Nav::Field("shape"),
                Nav::Node("Union"),
                Nav::Index(1),
                Nav::Node("Torus"),
                Nav::Field("minor"),
            ],
        );
        assert_eq!(
            place_of(src, at),
            Place {
                line: 4,
                column: 11
            }
        );
        let node = follow(src, 0, &[Nav::Field("shape"), Nav::Index(1)]);
        assert_eq!(place_of(src, node).line, 3);
    }

    #[test]
    fn a_number_is_one_token() {
        let text = "(a: -1.5e-3, b: [0x10, +2, .5])";
        let texts: Vec<&str> = tokens(text).iter().map(|t| &text[t.start..t.end]).collect();
        assert_eq!(
            texts,
            [
                "(", "a", ":", "-1.5e-3", ",", "b", ":", "[", "0x10", ",", "+2", ",", ".5", "]",
                ")"
            ]
        );
        assert_eq!(field(text, &["b"]), text.find('['));
    }

    #[test]
    fn multibyte_text_is_safe() {
        let src = "Scene(\u{a0}objects: [(name: \"é\"),\u{2003}(x: 1)], é: 1)";
        assert_eq!(list_elements(src, "objects").len(), 2);
        let _ = place_of(src, 8);
    }
}

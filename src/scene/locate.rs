//! Finding places in a scene file's text, for errors found after parsing (unknown material names,
//! shapes that cannot be lowered): the parser itself already reports syntax and value errors.

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
    let offset = offset.min(source.len());
    let before = &source[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map(|i| i + 1).unwrap_or(0);
    Place {
        line,
        column: source[line_start..offset].chars().count() + 1,
    }
}

/// Byte ranges of the elements of the top-level list field `field` (e.g. `objects`), found by
/// scanning brackets while skipping strings and comments. Returns an empty list when absent.
pub fn list_elements(source: &str, field: &str) -> Vec<(usize, usize)> {
    let bytes = source.as_bytes();
    let mut depth = 0usize;
    let mut i = 0;
    let mut list_depth = None;
    let mut elements = Vec::new();
    let mut element_start: Option<usize> = None;
    while i < bytes.len() {
        let c = bytes[i];
        match c {
            b'"' => {
                if let (Some(_), None) = (list_depth, element_start) {
                    element_start = Some(i);
                }
                i += 1;
                while i < bytes.len() && bytes[i] != b'"' {
                    if bytes[i] == b'\\' {
                        i += 1;
                    }
                    i += 1;
                }
            }
            b'/' if bytes.get(i + 1) == Some(&b'/') => {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
                continue;
            }
            b'/' if bytes.get(i + 1) == Some(&b'*') => {
                i += 2;
                while i + 1 < bytes.len() && !(bytes[i] == b'*' && bytes[i + 1] == b'/') {
                    i += 1;
                }
                i += 1;
            }
            b'(' | b'[' | b'{' => {
                if list_depth == Some(depth) && element_start.is_none() {
                    element_start = Some(i);
                }
                depth += 1;
            }
            b')' | b']' | b'}' => {
                depth = depth.saturating_sub(1);
                if list_depth == Some(depth + 1) && c == b']' {
                    if let Some(s) = element_start.take() {
                        elements.push((s, i));
                    }
                    return elements;
                }
            }
            b',' if list_depth == Some(depth) => {
                if let Some(s) = element_start.take() {
                    elements.push((s, i));
                }
            }
            _ if list_depth.is_none()
                && depth == 1
                && source[i..].starts_with(field)
                && !is_ident(bytes.get(i.wrapping_sub(1)).copied())
                && !is_ident(bytes.get(i + field.len()).copied()) =>
            {
                // `field` `:` `[`
                let rest = source[i + field.len()..].trim_start();
                if let Some(rest) = rest.strip_prefix(':') {
                    if let Some(pos) = rest.find('[') {
                        if rest[..pos].trim().is_empty() {
                            let open = source.len() - rest.len() + pos;
                            i = open + 1;
                            depth += 1;
                            list_depth = Some(depth);
                            continue;
                        }
                    }
                }
            }
            c if list_depth == Some(depth)
                && element_start.is_none()
                && !c.is_ascii_whitespace() =>
            {
                element_start = Some(i);
            }
            _ => {}
        }
        i += 1;
    }
    elements
}

fn is_ident(c: Option<u8>) -> bool {
    c.is_some_and(|c| c.is_ascii_alphanumeric() || c == b'_')
}

/// Offset of the first occurrence of `needle` within `range` of `source`, as a whole word.
pub fn find_in(source: &str, range: (usize, usize), needle: &str) -> Option<usize> {
    let hay = &source[range.0..range.1.min(source.len())];
    let mut from = 0;
    while let Some(pos) = hay[from..].find(needle) {
        let at = from + pos;
        let before = hay[..at].bytes().last();
        let after = hay.as_bytes().get(at + needle.len()).copied();
        let word_edge = !needle.starts_with(|c: char| c.is_alphanumeric()) || !is_ident(before);
        let word_end = !needle.ends_with(|c: char| c.is_alphanumeric()) || !is_ident(after);
        if word_edge && word_end {
            return Some(range.0 + at);
        }
        from = at + needle.len();
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_object_elements() {
        let src = "Scene(\n  camera: X,\n  objects: [\n    (shape: Sphere(radius: 1)), // c\n    (name: \"a,b\", shape: Box(half_extents: (1,1,1))),\n  ],\n)";
        let e = list_elements(src, "objects");
        assert_eq!(e.len(), 2);
        assert!(src[e[0].0..e[0].1].starts_with("(shape: Sphere"));
        assert!(src[e[1].0..e[1].1].starts_with("(name: \"a,b\""));
        assert_eq!(place_of(src, e[1].0), Place { line: 5, column: 5 });
        assert_eq!(find_in(src, e[1], "Box").map(|o| place_of(src, o).line), Some(5));
    }
}

//! Algebraic expressions in x, y, z for implicit surfaces: parsing and reference evaluation.
//!
//! Scene files may describe a surface as the zero set of an expression such as
//! `x*x + y*y + z*z - 1` or `sqrt(x^2+z^2) - 1 + 0.1*sin(4*y)`. [`parse`] turns such a
//! string into an [`Expr`] tree, which can be evaluated directly with [`Expr::eval`] (the
//! reference the SDF tape is checked against) and simplified with [`Expr::fold_constants`].
//!
//! # Grammar
//!
//! ```text
//! expr    := term (('+' | '-') term)*                  left associative
//! term    := unary (('*' | '/') unary)*                left associative
//! unary   := ('-' | '+') unary | power
//! power   := primary ('^' unary)?                      right associative, tighter than unary minus
//! primary := number | 'x' | 'y' | 'z' | 'pi' | 'e' | '(' expr ')' | function '(' args ')'
//! number  := digits ['.' digits] [('e'|'E') ['+'|'-'] digits]   also `.5` and `1.`
//! ```
//!
//! So `-x^2` is `-(x^2)`, `2^3^2` is `2^(3^2)` and `2^-1` is `0.5`. The one-argument functions
//! are `sin cos tan sqrt abs exp ln log floor` (`log` is the natural logarithm, like `ln`), the
//! two-argument ones `min max pow`. A minus sign directly in front of a numeric literal that is
//! not raised to a power is part of the literal: `-2` is `Const(-2.0)`, while `-2^2` is
//! `-(2^2)`.
//!
//! # Limits
//!
//! The resulting tree may be at most 128 levels deep (a long chain like `a + b + c + ...`
//! nests one level per operator; group terms with parentheses to keep it shallow), and the
//! source may nest parentheses, function calls, signs and exponents at most 256 levels deep. These bounds keep every recursive walk over an `Expr`
//! (evaluation, printing, lowering, dropping) far away from a stack overflow, and they are
//! chosen so that the [`Display`](fmt::Display) form of any expression accepted by [`parse`]
//! is itself accepted.

use std::fmt;

use glam::Vec3;

/// The deepest expression tree [`parse`] accepts (a leaf has depth 1).
const MAX_TREE_DEPTH: usize = 128;

/// How deeply parentheses, function calls, signs and exponents may nest in the source.
///
/// Twice the tree depth, because the fully-parenthesised printed form of a tree of depth `d`
/// needs up to `2 * d` levels (e.g. `(-(-(2.0)))`).
const MAX_NESTING: usize = 2 * MAX_TREE_DEPTH;

/// Every identifier the parser knows, for error messages.
const KNOWN_NAMES: &str =
    "x, y, z, pi, e, sin, cos, tan, sqrt, abs, exp, ln, log, floor, min, max, pow";

/// An algebraic expression in the coordinates `x`, `y` and `z` of a point.
#[derive(Debug, Clone, PartialEq)]
pub enum Expr {
    /// The x coordinate of the point.
    X,
    /// The y coordinate of the point.
    Y,
    /// The z coordinate of the point.
    Z,
    /// A constant. [`parse`] and [`Expr::fold_constants`] only ever produce finite constants.
    Const(f32),
    /// A one-argument operation: negation or a function such as `sin`.
    Unary(UnaryOp, Box<Expr>),
    /// A two-argument operation: an arithmetic operator or `min`, `max`, `pow`.
    Binary(BinaryOp, Box<Expr>, Box<Expr>),
}

/// The operation of an [`Expr::Unary`] node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UnaryOp {
    /// Negation, `-a`.
    Neg,
    /// Absolute value, `abs(a)`.
    Abs,
    /// Square root, `sqrt(a)` (NaN for negative `a`).
    Sqrt,
    /// Sine of an angle in radians, `sin(a)`.
    Sin,
    /// Cosine of an angle in radians, `cos(a)`.
    Cos,
    /// Tangent of an angle in radians, `tan(a)`.
    Tan,
    /// The exponential function, `exp(a)`.
    Exp,
    /// The natural logarithm, written `ln(a)` or `log(a)`.
    Ln,
    /// Rounding down to an integer, `floor(a)`.
    Floor,
}

/// The operation of an [`Expr::Binary`] node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BinaryOp {
    /// Addition, `a + b`.
    Add,
    /// Subtraction, `a - b`.
    Sub,
    /// Multiplication, `a * b`.
    Mul,
    /// Division, `a / b`.
    Div,
    /// The smaller operand, `min(a, b)`.
    Min,
    /// The larger operand, `max(a, b)`.
    Max,
    /// Exponentiation, `a ^ b` or `pow(a, b)`.
    Pow,
}

/// Why [`parse`] rejected an expression, and where.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("column {column}: {message}")]
pub struct ExprError {
    /// 1-based column, counted in characters, of the offending spot in the expression string;
    /// one past the last character when the input ended too early.
    pub column: usize,
    /// What went wrong, meant for the person who wrote the expression.
    pub message: String,
}

impl ExprError {
    fn new(column: usize, message: impl Into<String>) -> Self {
        ExprError {
            column,
            message: message.into(),
        }
    }
}

impl UnaryOp {
    fn apply(self, a: f32) -> f32 {
        match self {
            UnaryOp::Neg => -a,
            UnaryOp::Abs => a.abs(),
            UnaryOp::Sqrt => a.sqrt(),
            UnaryOp::Sin => a.sin(),
            UnaryOp::Cos => a.cos(),
            UnaryOp::Tan => a.tan(),
            UnaryOp::Exp => a.exp(),
            UnaryOp::Ln => a.ln(),
            UnaryOp::Floor => a.floor(),
        }
    }

    /// The function name, as printed (`Neg` is printed as a sign instead).
    fn name(self) -> &'static str {
        match self {
            UnaryOp::Neg => "-",
            UnaryOp::Abs => "abs",
            UnaryOp::Sqrt => "sqrt",
            UnaryOp::Sin => "sin",
            UnaryOp::Cos => "cos",
            UnaryOp::Tan => "tan",
            UnaryOp::Exp => "exp",
            UnaryOp::Ln => "ln",
            UnaryOp::Floor => "floor",
        }
    }
}

impl BinaryOp {
    fn apply(self, a: f32, b: f32) -> f32 {
        match self {
            BinaryOp::Add => a + b,
            BinaryOp::Sub => a - b,
            BinaryOp::Mul => a * b,
            BinaryOp::Div => a / b,
            BinaryOp::Min => a.min(b),
            BinaryOp::Max => a.max(b),
            BinaryOp::Pow => a.powf(b),
        }
    }

    /// The operator symbol or function name, as printed.
    fn name(self) -> &'static str {
        match self {
            BinaryOp::Add => "+",
            BinaryOp::Sub => "-",
            BinaryOp::Mul => "*",
            BinaryOp::Div => "/",
            BinaryOp::Min => "min",
            BinaryOp::Max => "max",
            BinaryOp::Pow => "^",
        }
    }
}

impl Expr {
    /// Evaluates the expression at `p` with plain `f32` arithmetic; the reference result.
    ///
    /// Follows IEEE semantics: `sqrt(-1)` is NaN, `1/0` is infinite, and so on.
    pub fn eval(&self, p: Vec3) -> f32 {
        match self {
            Expr::X => p.x,
            Expr::Y => p.y,
            Expr::Z => p.z,
            Expr::Const(c) => *c,
            Expr::Unary(op, a) => op.apply(a.eval(p)),
            Expr::Binary(op, a, b) => op.apply(a.eval(p), b.eval(p)),
        }
    }

    /// The number of nodes in the tree (leaves included).
    pub fn node_count(&self) -> usize {
        match self {
            Expr::X | Expr::Y | Expr::Z | Expr::Const(_) => 1,
            Expr::Unary(_, a) => 1 + a.node_count(),
            Expr::Binary(_, a, b) => 1 + a.node_count() + b.node_count(),
        }
    }

    /// Replaces every subtree that does not depend on x, y or z by its value.
    ///
    /// Only evaluation is performed, no algebra: `x^2` stays `Pow(X, Const(2))` and `x*1`
    /// stays as it is. A subtree whose value is not finite (such as `sqrt(-1)` or `1/0`) is
    /// left unfolded, so constants stay finite and printable; since folding runs the very
    /// same `f32` operations as [`Expr::eval`], the folded expression evaluates bit for bit
    /// like the original everywhere.
    pub fn fold_constants(self) -> Expr {
        match self {
            Expr::X | Expr::Y | Expr::Z | Expr::Const(_) => self,
            Expr::Unary(op, a) => {
                let a = a.fold_constants();
                if let Expr::Const(va) = a {
                    let v = op.apply(va);
                    if v.is_finite() {
                        return Expr::Const(v);
                    }
                }
                Expr::Unary(op, Box::new(a))
            }
            Expr::Binary(op, a, b) => {
                let a = a.fold_constants();
                let b = b.fold_constants();
                if let (Expr::Const(va), Expr::Const(vb)) = (&a, &b) {
                    let v = op.apply(*va, *vb);
                    if v.is_finite() {
                        return Expr::Const(v);
                    }
                }
                Expr::Binary(op, Box::new(a), Box::new(b))
            }
        }
    }
}

/// Prints the expression fully parenthesised, e.g. `((x ^ 2.0) + (-(sin(y))))`.
///
/// [`parse`] reads the output back to an equal `Expr` whenever all constants are finite
/// (always the case for expressions from [`parse`] and [`Expr::fold_constants`]). Negative
/// constants print as `(-2.0)`, and negation of a non-negative constant as `(-(2.0))`, so the
/// two stay distinct.
impl fmt::Display for Expr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Expr::X => f.write_str("x"),
            Expr::Y => f.write_str("y"),
            Expr::Z => f.write_str("z"),
            // `{:?}` is the shortest form that reads back to the same f32, in a syntax the
            // lexer accepts (`1.0`, `0.5`, `1e-7`, `3e20`).
            Expr::Const(c) if c.is_sign_negative() => write!(f, "({c:?})"),
            Expr::Const(c) => write!(f, "{c:?}"),
            Expr::Unary(UnaryOp::Neg, a) => match **a {
                // `-2.0` would read back as the literal `Const(-2.0)`.
                Expr::Const(c) if !c.is_sign_negative() => write!(f, "(-({a}))"),
                _ => write!(f, "(-{a})"),
            },
            Expr::Unary(op, a) => write!(f, "{}({a})", op.name()),
            Expr::Binary(op @ (BinaryOp::Min | BinaryOp::Max), a, b) => {
                write!(f, "{}({a}, {b})", op.name())
            }
            Expr::Binary(op, a, b) => write!(f, "({a} {} {b})", op.name()),
        }
    }
}

/// Parses an expression in x, y, z; see the [module documentation](self) for the grammar.
///
/// Never panics; every rejection comes with the 1-based character column of the problem.
pub fn parse(source: &str) -> Result<Expr, ExprError> {
    let tokens = lex(source)?;
    if tokens[0].kind == Tok::End {
        return Err(ExprError::new(
            1,
            "empty expression: expected something like `x*x + y*y + z*z - 1`",
        ));
    }
    let mut parser = Parser {
        tokens,
        pos: 0,
        nesting: 0,
    };
    let node = parser.sum()?;
    let next = parser.peek();
    match next.kind {
        Tok::End => Ok(node.expr),
        Tok::RParen => Err(ExprError::new(
            next.column,
            "unmatched `)`: there is no `(` for it to close",
        )),
        Tok::Comma => Err(ExprError::new(
            next.column,
            "unexpected `,` outside of a function call",
        )),
        _ => Err(ExprError::new(
            next.column,
            format!(
                "unexpected {} after a complete expression; expected an operator \
                 (+ - * / ^) or the end of the input{}",
                describe(next),
                implicit_multiplication_hint(next)
            ),
        )),
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Tok {
    Num(f32),
    Ident,
    Plus,
    Minus,
    Star,
    Slash,
    Caret,
    LParen,
    RParen,
    Comma,
    End,
}

#[derive(Debug, Clone, Copy)]
struct Token<'a> {
    kind: Tok,
    /// 1-based character column of the first character.
    column: usize,
    /// The source text of the token (empty for `End`).
    text: &'a str,
}

/// How a token is named in error messages.
fn describe(token: Token<'_>) -> String {
    match token.kind {
        Tok::End => "end of input".to_string(),
        _ => format!("`{}`", token.text),
    }
}

/// A hint for a token that directly follows a complete operand.
fn implicit_multiplication_hint(token: Token<'_>) -> &'static str {
    match token.kind {
        Tok::Num(_) | Tok::Ident | Tok::LParen => {
            " (implicit multiplication is not supported: write `*` between factors)"
        }
        _ => "",
    }
}

/// Splits the source into tokens, always ending with one `End` token.
fn lex(source: &str) -> Result<Vec<Token<'_>>, ExprError> {
    let chars: Vec<char> = source.chars().collect();
    // Byte offset of every character, plus one for the end of the string.
    let offsets: Vec<usize> = source
        .char_indices()
        .map(|(offset, _)| offset)
        .chain(std::iter::once(source.len()))
        .collect();
    let at = |i: usize| chars.get(i).copied();
    let digits_from = |mut i: usize| {
        while at(i).is_some_and(|c| c.is_ascii_digit()) {
            i += 1;
        }
        i
    };

    let mut tokens = Vec::new();
    let mut i = 0;
    while let Some(c) = at(i) {
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        let start = i;
        let column = start + 1;
        let single = match c {
            '+' => Some(Tok::Plus),
            '-' => Some(Tok::Minus),
            '*' => Some(Tok::Star),
            '/' => Some(Tok::Slash),
            '^' => Some(Tok::Caret),
            '(' => Some(Tok::LParen),
            ')' => Some(Tok::RParen),
            ',' => Some(Tok::Comma),
            _ => None,
        };
        let kind = if let Some(kind) = single {
            i += 1;
            kind
        } else if c.is_ascii_digit() || c == '.' {
            let int_end = digits_from(i);
            let mut end = int_end;
            if at(end) == Some('.') {
                end = digits_from(end + 1);
            }
            // Digits on either side of the point, i.e. more than just a `.`.
            if end - start == 1 && c == '.' {
                return Err(ExprError::new(
                    column,
                    "a lone `.` is not a number; write e.g. `0.5` or `.5`",
                ));
            }
            let mantissa_end = end;
            if let Some(e @ ('e' | 'E')) = at(end) {
                let mut exp_start = end + 1;
                if matches!(at(exp_start), Some('+' | '-')) {
                    exp_start += 1;
                }
                let exp_end = digits_from(exp_start);
                if exp_end == exp_start {
                    return Err(ExprError::new(
                        column,
                        format!(
                            "incomplete exponent in number `{}`: expected digits after `{e}` \
                             (to multiply by the constant e, write `*e`)",
                            &source[offsets[start]..offsets[exp_start]]
                        ),
                    ));
                }
                end = exp_end;
            }
            if at(end) == Some('.') {
                return Err(ExprError::new(
                    end + 1,
                    format!(
                        "malformed number: unexpected `.` after `{}`",
                        &source[offsets[start]..offsets[end]]
                    ),
                ));
            }
            let text = &source[offsets[start]..offsets[end]];
            let value: f32 = text
                .parse()
                .map_err(|_| ExprError::new(column, format!("malformed number `{text}`")))?;
            if !value.is_finite() {
                return Err(ExprError::new(
                    column,
                    format!(
                        "number `{text}` is too large for f32 (the largest finite value is \
                         about 3.4e38)"
                    ),
                ));
            }
            let mantissa = &source[offsets[start]..offsets[mantissa_end]];
            if value == 0.0 && mantissa.bytes().any(|b| matches!(b, b'1'..=b'9')) {
                return Err(ExprError::new(
                    column,
                    format!("number `{text}` is too small for f32: it would round to zero"),
                ));
            }
            i = end;
            Tok::Num(value)
        } else if c.is_ascii_alphabetic() || c == '_' {
            while at(i).is_some_and(|c| c.is_ascii_alphanumeric() || c == '_') {
                i += 1;
            }
            Tok::Ident
        } else {
            return Err(ExprError::new(
                column,
                format!(
                    "unexpected character `{}`; expected a number, a name, an operator \
                     (+ - * / ^), `(`, `)` or `,`",
                    c.escape_debug()
                ),
            ));
        };
        tokens.push(Token {
            kind,
            column,
            text: &source[offsets[start]..offsets[i]],
        });
    }
    tokens.push(Token {
        kind: Tok::End,
        column: chars.len() + 1,
        text: "",
    });
    Ok(tokens)
}

/// A parsed subtree together with its depth, so the depth limit costs nothing to check.
struct Node {
    expr: Expr,
    depth: usize,
}

impl Node {
    fn leaf(expr: Expr) -> Node {
        Node { expr, depth: 1 }
    }
}

/// What a function name stands for.
#[derive(Clone, Copy)]
enum Function {
    Unary(UnaryOp),
    Binary(BinaryOp),
}

fn function(name: &str) -> Option<Function> {
    Some(match name {
        "sin" => Function::Unary(UnaryOp::Sin),
        "cos" => Function::Unary(UnaryOp::Cos),
        "tan" => Function::Unary(UnaryOp::Tan),
        "sqrt" => Function::Unary(UnaryOp::Sqrt),
        "abs" => Function::Unary(UnaryOp::Abs),
        "exp" => Function::Unary(UnaryOp::Exp),
        "ln" | "log" => Function::Unary(UnaryOp::Ln),
        "floor" => Function::Unary(UnaryOp::Floor),
        "min" => Function::Binary(BinaryOp::Min),
        "max" => Function::Binary(BinaryOp::Max),
        "pow" => Function::Binary(BinaryOp::Pow),
        _ => return None,
    })
}

/// Variables and named constants.
fn atom(name: &str) -> Option<Expr> {
    Some(match name {
        "x" => Expr::X,
        "y" => Expr::Y,
        "z" => Expr::Z,
        "pi" => Expr::Const(std::f32::consts::PI),
        "e" => Expr::Const(std::f32::consts::E),
        _ => return None,
    })
}

struct Parser<'a> {
    tokens: Vec<Token<'a>>,
    /// Index of the next token; never moves past the final `End` token.
    pos: usize,
    /// Current recursion depth of `unary`, through which every recursive cycle passes.
    nesting: usize,
}

type Parsed = Result<Node, ExprError>;

impl<'a> Parser<'a> {
    fn peek(&self) -> Token<'a> {
        self.tokens[self.pos]
    }

    fn peek_kind(&self, ahead: usize) -> Tok {
        self.tokens
            .get(self.pos + ahead)
            .map_or(Tok::End, |token| token.kind)
    }

    fn advance(&mut self) -> Token<'a> {
        let token = self.tokens[self.pos];
        if token.kind != Tok::End {
            self.pos += 1;
        }
        token
    }

    fn unary_node(op: UnaryOp, a: Node, column: usize) -> Parsed {
        let depth = a.depth + 1;
        if depth > MAX_TREE_DEPTH {
            return Err(too_deep(column));
        }
        Ok(Node {
            expr: Expr::Unary(op, Box::new(a.expr)),
            depth,
        })
    }

    fn binary_node(op: BinaryOp, a: Node, b: Node, column: usize) -> Parsed {
        let depth = a.depth.max(b.depth) + 1;
        if depth > MAX_TREE_DEPTH {
            return Err(too_deep(column));
        }
        Ok(Node {
            expr: Expr::Binary(op, Box::new(a.expr), Box::new(b.expr)),
            depth,
        })
    }

    /// `term (('+' | '-') term)*`
    fn sum(&mut self) -> Parsed {
        let mut lhs = self.term()?;
        loop {
            let op = match self.peek().kind {
                Tok::Plus => BinaryOp::Add,
                Tok::Minus => BinaryOp::Sub,
                _ => return Ok(lhs),
            };
            let column = self.advance().column;
            let rhs = self.term()?;
            lhs = Self::binary_node(op, lhs, rhs, column)?;
        }
    }

    /// `unary (('*' | '/') unary)*`
    fn term(&mut self) -> Parsed {
        let mut lhs = self.unary()?;
        loop {
            let op = match self.peek().kind {
                Tok::Star => BinaryOp::Mul,
                Tok::Slash => BinaryOp::Div,
                _ => return Ok(lhs),
            };
            let column = self.advance().column;
            let rhs = self.unary()?;
            lhs = Self::binary_node(op, lhs, rhs, column)?;
        }
    }

    /// `('-' | '+') unary | primary ('^' unary)?`, guarding the recursion depth.
    ///
    /// Every recursive cycle of the parser passes through here, so counting calls bounds
    /// the stack; the frames on the way are kept small by building error messages in
    /// separate cold functions.
    fn unary(&mut self) -> Parsed {
        if self.nesting >= MAX_NESTING {
            return Err(nested_too_deeply(self.peek().column));
        }
        self.nesting += 1;
        let result = self.unary_unguarded();
        self.nesting -= 1;
        result
    }

    fn unary_unguarded(&mut self) -> Parsed {
        match self.peek().kind {
            Tok::Minus => {
                let column = self.advance().column;
                // A sign directly before a literal belongs to the literal, unless the
                // literal is the base of a power (`-2^2` is `-(2^2)`).
                match (self.peek_kind(0), self.peek_kind(1)) {
                    (Tok::Num(value), next) if next != Tok::Caret => {
                        self.advance();
                        Ok(Node::leaf(Expr::Const(-value)))
                    }
                    _ => {
                        let operand = self.unary()?;
                        Self::unary_node(UnaryOp::Neg, operand, column)
                    }
                }
            }
            Tok::Plus => {
                self.advance();
                self.unary()
            }
            _ => {
                let base = self.primary()?;
                if self.peek().kind != Tok::Caret {
                    return Ok(base);
                }
                let column = self.advance().column;
                let exponent = self.unary()?;
                Self::binary_node(BinaryOp::Pow, base, exponent, column)
            }
        }
    }

    /// A number, a name, a function call or a parenthesised expression.
    fn primary(&mut self) -> Parsed {
        let token = self.advance();
        match token.kind {
            Tok::Num(value) => Ok(Node::leaf(Expr::Const(value))),
            Tok::LParen => {
                let inner = self.sum()?;
                let close = self.peek();
                if close.kind != Tok::RParen {
                    return Err(missing_paren(token, close));
                }
                self.advance();
                Ok(inner)
            }
            Tok::Ident => {
                if let Some(expr) = atom(token.text) {
                    Ok(Node::leaf(expr))
                } else if let Some(function) = function(token.text) {
                    self.call(token, function)
                } else {
                    Err(unknown_identifier(token))
                }
            }
            _ => Err(expected_expression(token)),
        }
    }

    /// `name '(' [expr (',' expr)*] ')'`; `name` has already been consumed.
    fn call(&mut self, name: Token<'a>, function: Function) -> Parsed {
        let open = self.peek();
        if open.kind != Tok::LParen {
            return Err(missing_call_paren(name, open));
        }
        self.advance();
        let mut args = Vec::new();
        if self.peek().kind != Tok::RParen {
            loop {
                args.push(self.sum()?);
                if self.peek().kind != Tok::Comma {
                    break;
                }
                self.advance();
            }
        }
        let close = self.peek();
        if close.kind != Tok::RParen {
            return Err(unclosed_call(name, open, close));
        }
        self.advance();

        let count = args.len();
        let mut args = args.into_iter();
        match (function, args.next(), args.next()) {
            (Function::Unary(op), Some(a), None) => Self::unary_node(op, a, name.column),
            (Function::Binary(op), Some(a), Some(b)) if count == 2 => {
                Self::binary_node(op, a, b, name.column)
            }
            _ => Err(wrong_argument_count(name, function, count)),
        }
    }
}

// Error constructors, kept out of line so the recursive parser frames stay small.

#[cold]
#[inline(never)]
fn too_deep(column: usize) -> ExprError {
    ExprError::new(
        column,
        format!(
            "expression too deep: its tree would have more than {MAX_TREE_DEPTH} levels \
             (every operator in a chain like `a + b + c + ...` adds one; group terms with \
             parentheses to balance it)"
        ),
    )
}

#[cold]
#[inline(never)]
fn nested_too_deeply(column: usize) -> ExprError {
    ExprError::new(
        column,
        format!(
            "expression nested too deeply: more than {MAX_NESTING} levels of parentheses, \
             function calls, signs and exponents"
        ),
    )
}

#[cold]
#[inline(never)]
fn missing_paren(open: Token<'_>, found: Token<'_>) -> ExprError {
    ExprError::new(
        found.column,
        format!(
            "missing `)` to close the `(` at column {}; found {}{}",
            open.column,
            describe(found),
            implicit_multiplication_hint(found)
        ),
    )
}

#[cold]
#[inline(never)]
fn unknown_identifier(token: Token<'_>) -> ExprError {
    let lower = token.text.to_ascii_lowercase();
    let hint = if atom(&lower).is_some() || function(&lower).is_some() {
        format!(" (did you mean `{lower}`? names are case-sensitive)")
    } else {
        String::new()
    };
    ExprError::new(
        token.column,
        format!(
            "unknown identifier `{}`{hint}; known names are {KNOWN_NAMES}",
            token.text
        ),
    )
}

#[cold]
#[inline(never)]
fn expected_expression(found: Token<'_>) -> ExprError {
    ExprError::new(
        found.column,
        format!("expected an expression, found {}", describe(found)),
    )
}

#[cold]
#[inline(never)]
fn missing_call_paren(name: Token<'_>, found: Token<'_>) -> ExprError {
    ExprError::new(
        found.column,
        format!(
            "expected `(` after the function name `{}`, found {}",
            name.text,
            describe(found)
        ),
    )
}

#[cold]
#[inline(never)]
fn unclosed_call(name: Token<'_>, open: Token<'_>, found: Token<'_>) -> ExprError {
    ExprError::new(
        found.column,
        format!(
            "missing `)` to close the call to `{}` at column {}; found {}{}",
            name.text,
            open.column,
            describe(found),
            implicit_multiplication_hint(found)
        ),
    )
}

/// `given` is the number of arguments, already known to differ from the arity.
#[cold]
#[inline(never)]
fn wrong_argument_count(name: Token<'_>, function: Function, given: usize) -> ExprError {
    let (arity, usage) = match function {
        Function::Unary(_) => (1, "argument"),
        Function::Binary(_) => (2, "arguments"),
    };
    let given = match given {
        0 => "none was given".to_string(),
        1 => "1 was given".to_string(),
        n => format!("{n} were given"),
    };
    ExprError::new(
        name.column,
        format!(
            "function `{}` takes {arity} {usage}, but {given}",
            name.text
        ),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::vec3;

    fn c(v: f32) -> Expr {
        Expr::Const(v)
    }

    fn un(op: UnaryOp, a: Expr) -> Expr {
        Expr::Unary(op, Box::new(a))
    }

    fn bin(op: BinaryOp, a: Expr, b: Expr) -> Expr {
        Expr::Binary(op, Box::new(a), Box::new(b))
    }

    fn p(source: &str) -> Expr {
        match parse(source) {
            Ok(expr) => expr,
            Err(err) => {
                let head: String = source.chars().take(80).collect();
                panic!("failed to parse {head:?}...: {err}")
            }
        }
    }

    fn eval(source: &str, point: Vec3) -> f32 {
        p(source).eval(point)
    }

    fn same(a: f32, b: f32) -> bool {
        a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
    }

    use crate::rng::Rng;

    /// A random point in the cube [−3, 3]³.
    fn random_point(rng: &mut Rng) -> Vec3 {
        rng.in_cube(3.0).as_vec3()
    }

    use BinaryOp::{Add, Div, Max, Min, Mul, Pow, Sub};
    use Expr::{X, Y, Z};
    use UnaryOp::Neg;

    #[test]
    fn precedence_and_associativity() {
        assert_eq!(p("1 + 2 * 3"), bin(Add, c(1.0), bin(Mul, c(2.0), c(3.0))));
        assert_eq!(p("(1 + 2) * 3"), bin(Mul, bin(Add, c(1.0), c(2.0)), c(3.0)));
        assert_eq!(p("x - y - z"), bin(Sub, bin(Sub, X, Y), Z));
        assert_eq!(p("x / y / z"), bin(Div, bin(Div, X, Y), Z));
        assert_eq!(p("x / y * z"), bin(Mul, bin(Div, X, Y), Z));
        assert_eq!(p("x ^ y ^ z"), bin(Pow, X, bin(Pow, Y, Z)));
        assert_eq!(p("2*x^2"), bin(Mul, c(2.0), bin(Pow, X, c(2.0))));
        assert_eq!(p("-x^2"), un(Neg, bin(Pow, X, c(2.0))));
        assert_eq!(p("-2^2"), un(Neg, bin(Pow, c(2.0), c(2.0))));
        assert_eq!(eval("-2^2", Vec3::ZERO), -4.0);
        assert_eq!(p("-2"), c(-2.0));
        assert_eq!(p("- 2 * x"), bin(Mul, c(-2.0), X));
        assert_eq!(p("-x * y"), bin(Mul, un(Neg, X), Y));
        assert_eq!(p("x * -y"), bin(Mul, X, un(Neg, Y)));
        assert_eq!(p("x - -y"), bin(Sub, X, un(Neg, Y)));
        assert_eq!(p("--x"), un(Neg, un(Neg, X)));
        assert_eq!(p("+x"), X);
        assert_eq!(p("+-+x"), un(Neg, X));
        assert_eq!(p("2^-1"), bin(Pow, c(2.0), c(-1.0)));
        assert_eq!(p("2^-x^2"), bin(Pow, c(2.0), un(Neg, bin(Pow, X, c(2.0)))));
        assert_eq!(p("(-2)^2"), bin(Pow, c(-2.0), c(2.0)));
        assert_eq!(p("-(2)"), un(Neg, c(2.0)));
        assert_eq!(p("((x))"), X);
        assert_eq!(p("x*x + y*y + z*z - 1").node_count(), 13);
        assert_eq!(eval("2^3^2", Vec3::ZERO), 512.0);
        assert_eq!(eval("1 - 2 + 3", Vec3::ZERO), 2.0);
        assert_eq!(eval("8 / 4 / 2", Vec3::ZERO), 1.0);
        assert_eq!(eval("2^-1", Vec3::ZERO), 0.5);
        assert_eq!(eval("-x^2", vec3(3.0, 0.0, 0.0)), -9.0);
    }

    #[test]
    fn numbers_and_constants() {
        for (source, value) in [
            ("1", 1.0),
            ("1.5", 1.5),
            (".5", 0.5),
            ("1.", 1.0),
            ("1e-3", 1e-3),
            ("2.5E+2", 250.0),
            ("3e2", 300.0),
            ("0", 0.0),
            ("007", 7.0),
            ("1e-40", 1e-40),
            ("3.4e38", 3.4e38),
        ] {
            assert_eq!(p(source), c(value), "{source}");
        }
        assert_eq!(p("pi"), c(std::f32::consts::PI));
        assert_eq!(p("e"), c(std::f32::consts::E));
        assert_eq!(p("2*e"), bin(Mul, c(2.0), c(std::f32::consts::E)));
        assert_eq!(p(" \t x \n"), X);
    }

    #[test]
    fn every_function() {
        let point = vec3(0.7, -1.3, 2.2);
        let (x, y, z) = (point.x, point.y, point.z);
        let cases: [(&str, Expr, f32); 14] = [
            ("sin(x)", un(UnaryOp::Sin, X), x.sin()),
            ("cos(y)", un(UnaryOp::Cos, Y), y.cos()),
            ("tan(z)", un(UnaryOp::Tan, Z), z.tan()),
            ("sqrt(z)", un(UnaryOp::Sqrt, Z), z.sqrt()),
            ("abs(y)", un(UnaryOp::Abs, Y), 1.3),
            ("exp(x)", un(UnaryOp::Exp, X), x.exp()),
            ("ln(z)", un(UnaryOp::Ln, Z), z.ln()),
            ("log(z)", un(UnaryOp::Ln, Z), z.ln()),
            ("floor(y)", un(UnaryOp::Floor, Y), -2.0),
            ("min(x, y)", bin(Min, X, Y), y),
            ("max(x, y)", bin(Max, X, Y), x),
            ("pow(z, 2)", bin(Pow, Z, c(2.0)), z.powf(2.0)),
            ("z ^ 0.5", bin(Pow, Z, c(0.5)), z.powf(0.5)),
            ("-x", un(Neg, X), -0.7),
        ];
        for (source, expr, value) in cases {
            let parsed = p(source);
            assert_eq!(parsed, expr, "{source}");
            assert_eq!(parsed.eval(point), value, "{source}");
        }
        assert_eq!(
            p("min(max(x, 1), pow(y, z + 1))"),
            bin(Min, bin(Max, X, c(1.0)), bin(Pow, Y, bin(Add, Z, c(1.0))))
        );
        assert!(eval("sqrt(x)", vec3(-1.0, 0.0, 0.0)).is_nan());
    }

    #[test]
    fn eval_matches_hand_computed_values() {
        let sphere = "x*x + y*y + z*z - 1";
        assert_eq!(eval(sphere, vec3(1.0, 2.0, 2.0)), 8.0);
        assert_eq!(eval(sphere, vec3(0.0, 0.0, 0.0)), -1.0);
        assert_eq!(eval(sphere, vec3(0.0, 1.0, 0.0)), 0.0);

        let mix = "0.5*(max(abs(x),abs(y)) - 1) + 0.5*(x^2 + y^2 - 1)";
        // max(2, 1) - 1 = 1; 4 + 1 - 1 = 4; 0.5 * 1 + 0.5 * 4 = 2.5
        assert_eq!(eval(mix, vec3(-2.0, 1.0, 7.0)), 2.5);
        // max(0.5, 0) - 1 = -0.5; 0.25 - 1 = -0.75; -0.25 - 0.375 = -0.625
        assert_eq!(eval(mix, vec3(0.0, 0.5, 0.0)), -0.625);

        let torus_ish = "sqrt(x^2+z^2) - 1 + 0.1*sin(4*y)";
        // sqrt(9 + 16) - 1 + 0.1 * sin(0) = 4
        assert_eq!(eval(torus_ish, vec3(3.0, 0.0, 4.0)), 4.0);
        let point = vec3(0.6, 0.3, 0.8);
        let expected = 1.0f32.sqrt() - 1.0 + 0.1 * (4.0f32 * 0.3).sin();
        assert!((eval(torus_ish, point) - expected).abs() < 1e-6);

        assert_eq!(eval("10 / 4 - 2 * 3", Vec3::ZERO), -3.5);
        assert_eq!(eval("floor(-0.5) + floor(2.5)", Vec3::ZERO), 1.0);
        assert_eq!(eval("min(x, y) * max(y, z)", vec3(1.0, 2.0, 3.0)), 3.0);
        assert_eq!(eval("exp(0) + ln(1) + cos(0) + tan(0)", Vec3::ZERO), 2.0);
        assert_eq!(eval("abs(-3) + sqrt(16)", Vec3::ZERO), 7.0);
        assert!((eval("sin(pi/2) - e", Vec3::ZERO) - (1.0 - std::f32::consts::E)).abs() < 1e-6);
        assert_eq!(eval("1/x", Vec3::ZERO), f32::INFINITY);
    }

    #[test]
    fn error_columns() {
        let cases: &[(&str, usize, &str)] = &[
            ("", 1, "empty expression"),
            ("   ", 1, "empty expression"),
            ("x # y", 3, "unexpected character `#`"),
            ("x\u{a0}\u{a0}# y", 4, "unexpected character `#`"),
            ("ü + x", 1, "unexpected character `ü`"),
            ("x + foo", 5, "unknown identifier `foo`"),
            ("x + foo", 5, "known names are x, y, z, pi, e, sin"),
            ("Sin(x)", 1, "did you mean `sin`?"),
            ("w", 1, "unknown identifier `w`"),
            ("sin(x, y)", 1, "`sin` takes 1 argument, but 2 were given"),
            ("2 * min(x)", 5, "`min` takes 2 arguments, but 1 was given"),
            (
                "1 + max()",
                5,
                "`max` takes 2 arguments, but none was given",
            ),
            (
                "pow(1, 2, 3)",
                1,
                "`pow` takes 2 arguments, but 3 were given",
            ),
            ("sin x", 5, "expected `(` after the function name `sin`"),
            (
                "sin",
                4,
                "expected `(` after the function name `sin`, found end",
            ),
            ("(x + 1", 7, "missing `)` to close the `(` at column 1"),
            ("((x + 1)", 9, "missing `)` to close the `(` at column 1"),
            ("(x y)", 4, "implicit multiplication"),
            (
                "sin(x",
                6,
                "missing `)` to close the call to `sin` at column 4",
            ),
            ("x y", 3, "unexpected `y` after a complete expression"),
            ("2x", 2, "implicit multiplication"),
            ("x (y)", 3, "after a complete expression"),
            ("pi(2)", 3, "after a complete expression"),
            ("x)", 2, "unmatched `)`"),
            ("x, y", 2, "`,` outside of a function call"),
            ("1e39 + x", 1, "number `1e39` is too large for f32"),
            ("x * 1e-60", 5, "number `1e-60` is too small for f32"),
            (
                "x + 99999999999999999999999999999999999999999",
                5,
                "too large",
            ),
            ("x +", 4, "expected an expression, found end of input"),
            ("*x", 1, "expected an expression, found `*`"),
            ("x + )", 5, "expected an expression, found `)`"),
            ("min(x,)", 7, "expected an expression, found `)`"),
            ("2e", 1, "incomplete exponent in number `2e`"),
            ("1 + 3E+", 5, "incomplete exponent in number `3E+`"),
            (".", 1, "a lone `.`"),
            ("x + .", 5, "a lone `.`"),
            ("1.5.3", 4, "malformed number"),
        ];
        for &(source, column, needle) in cases {
            match parse(source) {
                Ok(expr) => panic!("{source:?} parsed as {expr}"),
                Err(err) => {
                    assert_eq!(err.column, column, "{source:?}: {err}");
                    assert!(
                        err.message.contains(needle),
                        "{source:?}: {err:?} does not mention {needle:?}"
                    );
                    assert_eq!(err.to_string(), format!("column {column}: {}", err.message));
                }
            }
        }
    }

    #[test]
    fn nesting_and_depth_limits() {
        let deep = format!("{}x{}", "(".repeat(10_000), ")".repeat(10_000));
        let err = parse(&deep).unwrap_err();
        assert_eq!(err.column, MAX_NESTING + 1);
        assert!(err.message.contains("nested too deeply"), "{err}");

        for source in [
            "-".repeat(100_000) + "x",
            "2^".repeat(100_000) + "2",
            "sin(".repeat(100_000),
            "(".repeat(100_000),
            "min(x,".repeat(100_000),
        ] {
            let err = parse(&source).unwrap_err();
            assert!(err.message.contains("nested too deeply"), "{err}");
        }

        let long_sum = "x+".repeat(100_000) + "x";
        let err = parse(&long_sum).unwrap_err();
        assert!(err.message.contains("expression too deep"), "{err}");
        assert_eq!(err.column, 2 * MAX_TREE_DEPTH);

        // Just inside both limits.
        let ok = format!(
            "{}x{}",
            "(".repeat(MAX_NESTING - 1),
            ")".repeat(MAX_NESTING - 1)
        );
        assert_eq!(p(&ok), X);
        let sum = "x+".repeat(MAX_TREE_DEPTH - 1) + "x";
        assert_eq!(p(&sum).node_count(), 2 * MAX_TREE_DEPTH - 1);
        // Balanced with parentheses, far more terms fit.
        let group = format!("({})", "x+".repeat(49) + "x");
        let balanced = vec![group; 50].join("+");
        assert_eq!(p(&balanced).eval(vec3(1.0, 0.0, 0.0)), 2_500.0);
    }

    #[test]
    fn printed_worst_cases_at_the_depth_limit_read_back() {
        let mut negs = c(2.0);
        let mut pows = c(-2.0);
        let mut mixed = X;
        for level in 1..MAX_TREE_DEPTH {
            negs = un(Neg, negs);
            pows = bin(Pow, Y, pows);
            mixed = if level % 2 == 0 {
                un(Neg, mixed)
            } else {
                bin(Pow, c(-1.0), mixed)
            };
        }
        for expr in [negs, pows, mixed] {
            let printed = expr.to_string();
            assert_eq!(parse(&printed), Ok(expr));
            let too_deep = format!("-{printed}");
            assert!(parse(&too_deep).is_err());
        }
    }

    #[test]
    fn display_round_trips() {
        let sources = [
            "x*x + y*y + z*z - 1",
            "0.5*(max(abs(x),abs(y)) - 1) + 0.5*(x^2 + y^2 - 1)",
            "sqrt(x^2+z^2) - 1 + 0.1*sin(4*y)",
            "-x^2",
            "-2^2",
            "-2",
            "-(2)",
            "-(-2)",
            "--x",
            "2^-3",
            "2^3^2",
            "(-2)^3",
            "x - -1",
            "x - -y",
            "-0",
            "-(0)",
            "1e-7*x + 3e20*y - 1.5e-30",
            "pi*e + 0.1 + 1/3",
            "min(-1, -x) / max(y, -z)",
            "pow(x, 2) + pow(-y, -0.5)",
            "exp(-x*x) * cos(y) * tan(z) + ln(abs(x) + 1) - log(2) + floor(y*3)",
            "x / y / z - x ^ y ^ z",
        ];
        for source in sources {
            let expr = p(source);
            let printed = expr.to_string();
            assert_eq!(p(&printed), expr, "{source} printed as {printed}");
            let folded = expr.fold_constants();
            let printed = folded.to_string();
            assert_eq!(p(&printed), folded, "{source} folded, printed as {printed}");
        }
        assert_eq!(p("-x^2").to_string(), "(-(x ^ 2.0))");
        assert_eq!(p("-2").to_string(), "(-2.0)");
        assert_eq!(p("-(2)").to_string(), "(-(2.0))");
        assert_eq!(p("min(x, 1e-7)").to_string(), "min(x, 1e-7)");
        assert_eq!(p("log(y)").to_string(), "ln(y)");
    }

    #[test]
    fn fold_constants_structure() {
        assert_eq!(p("2*3 + x").fold_constants(), bin(Add, c(6.0), X));
        assert_eq!(p("x^2").fold_constants(), bin(Pow, X, c(2.0)));
        assert_eq!(p("x^(1+1)").fold_constants(), bin(Pow, X, c(2.0)));
        assert_eq!(p("-2^2").fold_constants(), c(-4.0));
        assert_eq!(p("-(2)").fold_constants(), c(-2.0));
        assert_eq!(
            p("max(1, 2) * min(y, pi - pi)").fold_constants(),
            bin(Mul, c(2.0), bin(Min, Y, c(0.0)))
        );
        assert_eq!(p("x * 1 + 0").fold_constants(), p("x * 1 + 0"));
        // Non-finite values stay unfolded, so constants stay finite.
        assert_eq!(p("sqrt(-1) * x").fold_constants(), p("sqrt(-1) * x"));
        assert_eq!(
            p("(1/0) + 2*2").fold_constants(),
            bin(Add, bin(Div, c(1.0), c(0.0)), c(4.0))
        );
        assert_eq!(p("sin(1) + 1").fold_constants(), c(1.0f32.sin() + 1.0));
        assert_eq!(p("x + y").fold_constants().node_count(), 3);
    }

    #[test]
    fn fold_constants_preserves_eval() {
        let sources = [
            "2*3 + x",
            "sin(pi/2)*x + cos(0)*y - sqrt(2)*z",
            "sqrt(-1) + x",
            "ln(0) * 0 + x",
            "1/0 - y",
            "pow(2, 10) - x^2 + 2^0.5^2",
            "floor(2.7) * exp(1) - e*y + floor(x)",
            "max(1, 2) - min(x, 3) + abs(-4) / tan(1)",
            "-(2) * x + -(-(3)) - -y^2",
            "0.5*(max(abs(x),abs(y)) - 1) + 0.5*(x^2 + y^2 - 1)",
            "sqrt(x^2+z^2) - 1 + 0.1*sin(4*y) + ln(3)*log(z*z)",
            "(1 + 2 + 3) * (x + 1 + 2) / (4 - 2 * 2 + y)",
        ];
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        for source in sources {
            let expr = p(source);
            let folded = expr.clone().fold_constants();
            assert!(folded.node_count() <= expr.node_count());
            for _ in 0..200 {
                let point = random_point(&mut rng);
                let (a, b) = (expr.eval(point), folded.eval(point));
                assert!(same(a, b), "{source} at {point}: {a} vs folded {b}");
            }
        }
    }

    #[test]
    fn fuzz_never_panics() {
        const FRAGMENTS: &[&str] = &[
            "x", "y", "z", "pi", "e", "sin", "cos", "tan", "sqrt", "abs", "exp", "ln", "log",
            "floor", "min", "max", "pow", "(", "(", ")", ")", ",", "+", "-", "-", "*", "/", "^",
            " ", "0", "1", "2.5", ".", ".5", "e", "E", "1e", "1e-3", "9", "3", "1e39", "#", "é",
            "\t", "foo", "_", "X",
        ];
        const CHARS: &[u8] = b"xyz0123456789.eE+-*/^(), \tpisnqrtbamxlgfo_";
        let mut rng = Rng(0x0123_4567_89ab_cdef);
        let mut parsed = 0;
        for round in 0..6000 {
            let mut source = String::new();
            let len = rng.below(40) as usize;
            for _ in 0..len {
                if round % 3 == 0 {
                    source.push(CHARS[rng.below(CHARS.len() as u64) as usize] as char);
                } else {
                    source.push_str(FRAGMENTS[rng.below(FRAGMENTS.len() as u64) as usize]);
                }
            }
            match parse(&source) {
                Ok(expr) => {
                    parsed += 1;
                    let point = random_point(&mut rng);
                    let value = expr.eval(point);
                    assert!(expr.node_count() >= 1);
                    let printed = expr.to_string();
                    assert_eq!(
                        parse(&printed).as_ref(),
                        Ok(&expr),
                        "{source:?} -> {printed}"
                    );
                    let folded = expr.fold_constants();
                    assert!(same(folded.eval(point), value), "{source:?}");
                    let printed = folded.to_string();
                    assert_eq!(parse(&printed), Ok(folded), "{source:?} -> {printed}");
                }
                Err(err) => {
                    let chars = source.chars().count();
                    assert!(
                        (1..=chars + 1).contains(&err.column),
                        "{source:?}: column {} out of range",
                        err.column
                    );
                    assert!(!err.message.is_empty());
                }
            }
        }
        // The generator must actually reach the success path now and then.
        assert!(parsed > 50, "only {parsed} random inputs parsed");
    }
}

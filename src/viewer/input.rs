//! The viewer's input events and key bindings, independent of the window system: the window
//! translates its events into these, and scripts write them directly.

/// A mouse button the viewer uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Button {
    /// Orbit (drag), pick the pivot (click); with shift held, pan.
    Left,
    /// Pan.
    Middle,
}

/// A key the viewer knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Key {
    /// A letter (lower case), digit or sign, as typed.
    Char(char),
    /// Close the window.
    Escape,
    /// Print the key bindings.
    F1,
}

impl Key {
    /// Named keys a script may write besides single characters.
    pub const NAMES: &'static str = "Escape, F1, Plus, Minus";

    /// A key from a script word: one character, or a name of [`Key::NAMES`].
    pub fn parse(word: &str) -> Option<Key> {
        let mut chars = word.chars();
        match (chars.next(), chars.next()) {
            (Some(c), None) if c.is_ascii_graphic() => Some(Key::Char(c.to_ascii_lowercase())),
            _ => match word.to_ascii_lowercase().as_str() {
                "escape" | "esc" => Some(Key::Escape),
                "f1" => Some(Key::F1),
                "plus" => Some(Key::Char('+')),
                "minus" => Some(Key::Char('-')),
                _ => None,
            },
        }
    }
}

/// One input event, in window pixels from the top-left corner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Input {
    /// The cursor moved to (x, y).
    Move {
        /// Column.
        x: f32,
        /// Row.
        y: f32,
    },
    /// A button went down at the cursor.
    Press(Button),
    /// A button came up.
    Release(Button),
    /// The wheel turned by this many notches (positive: away from the user, zoom in).
    Scroll(f32),
    /// A key was pressed (key repeat sends it again).
    Key(Key),
    /// Shift went down (true) or up.
    Shift(bool),
}

/// What each key does, for `F1`, `--help` and the README.
pub const KEY_HELP: &[(&str, &str)] = &[
    ("left drag", "orbit about the pivot"),
    ("middle drag, shift + left drag", "pan"),
    ("wheel", "zoom (dolly toward the pivot)"),
    (
        "left click on a surface",
        "make the point the pivot and look at it",
    ),
    ("W A S D, Q E", "fly forward, left, back, right, down, up"),
    ("F", "frame everything"),
    ("R", "reset to the scene's camera"),
    ("C", "print the camera as a scene-file snippet (stdout)"),
    (
        "P",
        "screenshot: the refined image as `hytrace render` writes it",
    ),
    (
        "V",
        "cycle the view: shaded, normals, depth, steps, gradient",
    ),
    ("T", "cycle the stepper: hart, relaxed, adaptive, segment"),
    ("H", "shadows on/off"),
    ("O", "ambient occlusion on/off"),
    ("+ / -", "exposure up/down half a stop"),
    ("F1", "print these keys"),
    ("Escape", "close the window"),
];

//! Viewer scripts: timed input events and commands (`--script FILE`), so the viewer runs
//! without a person — in tests, in the benchmark and for recorded camera moves.
//!
//! One command per line, `#` starts a comment:
//!
//! ```text
//! wait 0.5                     # seconds; the viewer goes on rendering meanwhile
//! converge                     # wait until the image is refined to all its samples
//! drag 400 300 520 300         # left-button drag (orbit) in window pixels, in 8 moves
//! drag 400 300 520 300 middle  # middle button (pan); `shift` is shift + left (pan)
//! drag 400 300 520 300 left 30 # ... in 30 moves
//! click 400 300                # left click without moving: the surface point becomes the pivot
//! scroll 2                     # wheel notches (positive: toward the pivot)
//! key f                        # press and release a key, as typed (see `Key::parse`)
//! print-camera                 # as the C key: the camera as a scene-file snippet on stdout
//! screenshot out.png           # as the P key, to this file (.png, or .exr with --aov)
//! window-shot shown.png        # what the window shows, the heads-up line included
//! wait-reload                  # wait until the scene file has been reloaded (or failed to)
//! stats                        # print frame rate while moving and time to converge, since
//!                              # the last `stats`, as one line on stdout
//! quit
//! ```

use super::input::{Button, Input, Key};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// One step of a script.
#[derive(Debug, Clone, PartialEq)]
pub enum Step {
    /// Go on rendering for this long.
    Wait(Duration),
    /// Wait until the image has all its samples.
    Converge,
    /// Feed this input event, as if it came from the window.
    Input(Input),
    /// Print the camera.
    PrintCamera,
    /// Write the refined image to this file.
    Screenshot(PathBuf),
    /// Write what the window shows to this file.
    WindowShot(PathBuf),
    /// Wait for the next reload of the scene file.
    WaitReload,
    /// Print the frame statistics gathered since the last `stats` and start again.
    Stats,
    /// Close the window.
    Quit,
}

/// Pause between the moves of a scripted drag: long enough that a preview frame renders
/// between them, as it would under a hand.
pub const DRAG_MOVE_PAUSE: Duration = Duration::from_millis(15);

/// Reads a script file.
pub fn load(path: &Path) -> Result<Vec<Step>, String> {
    let text = crate::scene::read::read_to_string(path)
        .map_err(|e| format!("{}: cannot read the script: {e}", path.display()))?;
    parse(&text).map_err(|(line, message)| format!("{}:{line}: {message}", path.display()))
}

/// Parses a script; an error says on which line (from 1) and what is wrong.
pub fn parse(text: &str) -> Result<Vec<Step>, (usize, String)> {
    let mut steps = Vec::new();
    for (number, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        parse_line(line, &mut steps).map_err(|m| (number + 1, m))?;
    }
    Ok(steps)
}

fn parse_line(line: &str, steps: &mut Vec<Step>) -> Result<(), String> {
    let words: Vec<&str> = line.split_whitespace().collect();
    let (command, args) = (words[0], &words[1..]);
    let number = |i: usize| -> Result<f32, String> {
        let word = args
            .get(i)
            .ok_or_else(|| format!("`{command}` needs more arguments"))?;
        word.parse::<f32>()
            .ok()
            .filter(|v| v.is_finite() && v.abs() <= 1e6)
            .ok_or_else(|| format!("`{word}` is not a number within ±1e6"))
    };
    let arity = |n: std::ops::RangeInclusive<usize>| {
        if n.contains(&args.len()) {
            Ok(())
        } else {
            Err(format!(
                "`{command}` takes {} argument(s), found {}",
                if n.start() == n.end() {
                    n.start().to_string()
                } else {
                    format!("{} to {}", n.start(), n.end())
                },
                args.len()
            ))
        }
    };
    // one file name, of one of the `kinds` of image the step writes (as `--screenshot` asks)
    let file = |args: &[&str], kinds: &[&str]| -> Result<PathBuf, String> {
        let [name] = args else {
            return Err(format!("`{command}` takes one file name"));
        };
        let path = PathBuf::from(name);
        let ext = (path.extension().and_then(|e| e.to_str())).map(str::to_ascii_lowercase);
        if !ext.is_some_and(|e| kinds.contains(&e.as_str())) {
            let names = kinds.iter().map(|k| format!(".{k}")).collect::<Vec<_>>();
            return Err(format!(
                "{command} {name}: use a {} file name",
                names.join(" or ")
            ));
        }
        Ok(path)
    };
    match command {
        "wait" => {
            arity(1..=1)?;
            let seconds = number(0)?;
            if !(0.0..=3600.0).contains(&seconds) {
                return Err(format!("wait {seconds}: seconds must be in 0..=3600"));
            }
            steps.push(Step::Wait(Duration::from_secs_f32(seconds)));
        }
        "converge" => {
            arity(0..=0)?;
            steps.push(Step::Converge);
        }
        "drag" => {
            arity(4..=6)?;
            let (x0, y0, x1, y1) = (number(0)?, number(1)?, number(2)?, number(3)?);
            let (button, shift) = match args.get(4).copied().unwrap_or("left") {
                "left" => (Button::Left, false),
                "middle" => (Button::Middle, false),
                "shift" => (Button::Left, true),
                other => return Err(format!("drag button `{other}`: use left, middle or shift")),
            };
            let moves = match args.get(5) {
                None => 8,
                Some(_) => {
                    let n = number(5)?;
                    if !(1.0..=1000.0).contains(&n) || n.fract() != 0.0 {
                        return Err(format!("drag moves {n}: a whole number in 1..=1000"));
                    }
                    n as u32
                }
            };
            if shift {
                steps.push(Step::Input(Input::Shift(true)));
            }
            steps.push(Step::Input(Input::Move { x: x0, y: y0 }));
            steps.push(Step::Input(Input::Press(button)));
            for i in 1..=moves {
                let t = i as f32 / moves as f32;
                steps.push(Step::Wait(DRAG_MOVE_PAUSE));
                steps.push(Step::Input(Input::Move {
                    x: x0 + t * (x1 - x0),
                    y: y0 + t * (y1 - y0),
                }));
            }
            steps.push(Step::Input(Input::Release(button)));
            if shift {
                steps.push(Step::Input(Input::Shift(false)));
            }
        }
        "click" => {
            arity(2..=2)?;
            steps.push(Step::Input(Input::Move {
                x: number(0)?,
                y: number(1)?,
            }));
            steps.push(Step::Input(Input::Press(Button::Left)));
            steps.push(Step::Input(Input::Release(Button::Left)));
        }
        "scroll" => {
            arity(1..=1)?;
            steps.push(Step::Input(Input::Scroll(number(0)?)));
        }
        "key" => {
            arity(1..=1)?;
            let key = Key::parse(args[0]).ok_or_else(|| {
                format!(
                    "unknown key `{}` (a letter or digit, or one of {})",
                    args[0],
                    Key::NAMES
                )
            })?;
            steps.push(Step::Input(Input::Key(key)));
        }
        "print-camera" => {
            arity(0..=0)?;
            steps.push(Step::PrintCamera);
        }
        "screenshot" => steps.push(Step::Screenshot(file(args, &["png", "exr"])?)),
        "window-shot" => steps.push(Step::WindowShot(file(args, &["png"])?)),
        "wait-reload" => {
            arity(0..=0)?;
            steps.push(Step::WaitReload);
        }
        "stats" => {
            arity(0..=0)?;
            steps.push(Step::Stats);
        }
        "quit" => {
            arity(0..=0)?;
            steps.push(Step::Quit);
        }
        other => {
            return Err(format!(
                "unknown command `{other}` (wait, converge, drag, click, scroll, key, \
                 print-camera, screenshot, window-shot, wait-reload, stats, quit)"
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_drag_becomes_press_moves_release() {
        let steps = parse("drag 10 20 30 20 middle 2\n").unwrap();
        let inputs: Vec<&Input> = steps
            .iter()
            .filter_map(|s| match s {
                Step::Input(i) => Some(i),
                _ => None,
            })
            .collect();
        assert_eq!(
            inputs,
            [
                &Input::Move { x: 10.0, y: 20.0 },
                &Input::Press(Button::Middle),
                &Input::Move { x: 20.0, y: 20.0 },
                &Input::Move { x: 30.0, y: 20.0 },
                &Input::Release(Button::Middle),
            ]
        );
    }

    #[test]
    fn every_command_parses_and_comments_are_skipped() {
        let text = "# a comment\nwait 0.25\nconverge\nclick 1 2 # pick\nscroll -1\nkey f\n\
                    key Escape\nprint-camera\nscreenshot a.png\nwindow-shot b.png\nwait-reload\nquit\n";
        let steps = parse(text).unwrap();
        assert_eq!(steps[0], Step::Wait(Duration::from_millis(250)));
        assert_eq!(steps.last(), Some(&Step::Quit));
        assert!(steps.contains(&Step::Input(Input::Key(Key::Char('f')))));
        assert!(steps.contains(&Step::Input(Input::Key(Key::Escape))));
        assert!(steps.contains(&Step::Screenshot("a.png".into())));
    }

    #[test]
    fn errors_name_the_line() {
        assert_eq!(parse("wait 1\nfly away\n").unwrap_err().0, 2);
        assert!(parse("wait NaN").unwrap_err().1.contains("not a number"));
        assert!(parse("wait 1e9").is_err());
        assert!(parse("drag 1 2 3").unwrap_err().1.contains("argument"));
        assert!(
            parse("drag 1 2 3 4 right")
                .unwrap_err()
                .1
                .contains("left, middle")
        );
        assert!(
            parse("key NoSuchKey")
                .unwrap_err()
                .1
                .contains("unknown key")
        );
        assert!(parse("screenshot").is_err());
        // the image kinds the steps write, as `--screenshot` asks
        assert!(parse("screenshot a.exr").is_ok() && parse("screenshot A.PNG").is_ok());
        for bad in ["screenshot a.jpg", "screenshot a", "window-shot a.exr"] {
            let (_, e) = parse(bad).expect_err(bad);
            assert!(e.contains("use a .png"), "{bad}: {e}");
        }
    }
}

//! `hytrace view` end to end, in a real window on a virtual X server (Xvfb) presented through
//! wgpu on Mesa's lavapipe: screenshots equal `hytrace render` byte for byte, a scripted orbit
//! and real input events (xdotool) move the camera that `C` prints, hot reload survives a
//! broken edit, and a missing display or Vulkan driver gives one line and a non-zero exit.
//!
//! Xvfb and xdotool come from `scripts/setup.sh`; when either is missing the tests fail and
//! say so (they never skip).

mod common;
use common::assets;

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The longest a viewer run may take before the test calls it hung.
const VIEWER_TIMEOUT: Duration = Duration::from_secs(180);

/// The shipped showcase scene: the built-in one `hytrace view` opens without a file.
const SHOWCASE: &str = include_str!("../assets/scenes/showcase.ron");

fn hytrace() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_hytrace"));
    c.env("HYTRACE_ASSETS", assets());
    c
}

/// A virtual X server on a display number of its own, stopped on drop.
struct Xvfb {
    child: Child,
    display: String,
}

impl Xvfb {
    fn start() -> Xvfb {
        // -displayfd: Xvfb picks a free display and writes its number once it accepts clients
        let mut child = Command::new("Xvfb")
            .args([
                "-displayfd",
                "1",
                "-screen",
                "0",
                "1024x768x24",
                "-nolisten",
                "tcp",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("cannot start Xvfb: scripts/setup.sh installs it (Debian package xvfb)");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("piped"))
            .read_line(&mut line)
            .expect("Xvfb's display number");
        let number = line.trim();
        assert!(
            !number.is_empty() && number.chars().all(|c| c.is_ascii_digit()),
            "Xvfb did not say its display: {line:?}"
        );
        Xvfb {
            child,
            display: format!(":{number}"),
        }
    }

    /// `hytrace view ARGS` on this display.
    fn view(&self, args: &[&str]) -> Command {
        let mut c = hytrace();
        c.arg("view").args(args).env("DISPLAY", &self.display);
        c.env_remove("WAYLAND_DISPLAY");
        c
    }

    /// `hytrace view SCENE` in a `width`×`height` window refining to one sample, run by
    /// `script`, started and left running (its output piped).
    fn spawn_scripted(&self, scene: &Path, width: &str, height: &str, script: &Path) -> Child {
        let mut args = vec![scene.to_str().expect("utf-8")];
        args.extend(scripted(width, height, "1", script));
        self.view(&args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn hytrace view")
    }

    fn xdotool(&self, args: &[&str]) -> String {
        let out = Command::new("xdotool")
            .args(args)
            .env("DISPLAY", &self.display)
            .output()
            .expect("cannot run xdotool: scripts/setup.sh installs it (Debian package xdotool)");
        assert!(
            out.status.success(),
            "xdotool {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Waits for a child with a deadline; kills it and fails the test when it hangs.
fn finish(mut child: Child, what: &str) -> Output {
    let deadline = Instant::now() + VIEWER_TIMEOUT;
    loop {
        if child.try_wait().expect("wait for the viewer").is_some() {
            break;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let out = child.wait_with_output().expect("viewer output");
            panic!(
                "{what}: still running after {VIEWER_TIMEOUT:?}; stderr:\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let mut out = Output {
        status: child.wait().expect("status"),
        stdout: Vec::new(),
        stderr: Vec::new(),
    };
    if let Some(mut s) = child.stdout.take() {
        s.read_to_end(&mut out.stdout).expect("stdout");
    }
    if let Some(mut s) = child.stderr.take() {
        s.read_to_end(&mut out.stderr).expect("stderr");
    }
    out
}

/// `--width W --height H --spp S --backend cpu`.
fn cpu_options<'a>(width: &'a str, height: &'a str, spp: &'a str) -> [&'a str; 8] {
    [
        "--width",
        width,
        "--height",
        height,
        "--spp",
        spp,
        "--backend",
        "cpu",
    ]
}

/// The options of a window of `width`×`height` refining to `spp` samples on the CPU and run
/// by `script`.
fn scripted<'a>(width: &'a str, height: &'a str, spp: &'a str, script: &'a Path) -> Vec<&'a str> {
    let mut options = cpu_options(width, height, spp).to_vec();
    options.extend(["--script", script.to_str().expect("utf-8")]);
    options
}

/// Runs a command to the end, with the deadline.
fn run(mut command: Command, what: &str) -> Output {
    let child = command
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn hytrace");
    finish(child, what)
}

fn assert_ok(out: &Output, what: &str) {
    assert!(
        out.status.success(),
        "{what} failed ({}):\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `hytrace render SCENE -o OUT EXTRA...` (the built-in showcase when `scene` is None).
fn render(scene: Option<&Path>, out: &Path, extra: &[&str]) {
    let mut c = hytrace();
    c.arg("render");
    if let Some(s) = scene {
        c.arg(s);
    }
    c.arg("-q").arg("-o").arg(out).args(extra);
    let o = run(c, "hytrace render");
    assert_ok(&o, "hytrace render");
}

/// Peak signal-to-noise ratio of two 8-bit image files of one size, in dB (infinite when
/// equal).
fn psnr(a: &Path, b: &Path) -> f64 {
    let a = image::open(a).expect("image a").to_rgb8();
    let b = image::open(b).expect("image b").to_rgb8();
    common::psnr(&a, &b)
}

/// The screenshot must be what `render` writes: same bytes (which implies PSNR = ∞ ≥ 40 dB).
fn assert_same_image(shot: &Path, rendered: &Path) {
    let a = std::fs::read(shot).unwrap_or_else(|e| panic!("{}: {e}", shot.display()));
    let b = std::fs::read(rendered).unwrap_or_else(|e| panic!("{}: {e}", rendered.display()));
    if a != b {
        let db = if shot.extension().is_some_and(|e| e == "png") {
            format!("{:.1} dB", psnr(shot, rendered))
        } else {
            "an EXR".into()
        };
        panic!(
            "{} differs from {} (PSNR {db})",
            shot.display(),
            rendered.display()
        );
    }
}

/// The scene text with its camera replaced by the `camera: ...` line the viewer printed.
fn with_camera(scene: &str, printed: &str) -> String {
    let line = printed
        .lines()
        .find(|l| l.trim_start().starts_with("camera:"))
        .unwrap_or_else(|| panic!("no camera line in the viewer's output:\n{printed}"));
    let mut replaced = 0;
    let text: Vec<String> = scene
        .lines()
        .map(|l| {
            if l.trim_start().starts_with("camera:") {
                replaced += 1;
                format!("    {}", line.trim())
            } else {
                l.to_string()
            }
        })
        .collect();
    assert_eq!(replaced, 1, "the scene has one camera line");
    text.join("\n")
}

fn scene_camera(scene: &str) -> &str {
    scene
        .lines()
        .find(|l| l.trim_start().starts_with("camera:"))
        .expect("camera line")
}

#[test]
fn screenshot_equals_render_png_and_exr() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let csg = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes/csg.ron");
    for (name, scene) in [("showcase", None), ("csg", Some(csg.as_path()))] {
        let shot = dir.path().join(format!("{name}-view.png"));
        let mut args: Vec<String> = scene.map(|s| s.display().to_string()).into_iter().collect();
        args.extend(
            [
                "--width",
                "160",
                "--height",
                "120",
                "--spp",
                "3",
                "--backend",
                "cpu",
                "--aov",
                "depth,normal,steps",
                "--screenshot",
            ]
            .map(String::from),
        );
        args.push(shot.display().to_string());
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = run(x.view(&refs), "hytrace view --screenshot");
        assert_ok(&out, "hytrace view --screenshot");
        let png = dir.path().join(format!("{name}-render.png"));
        let exr = dir.path().join(format!("{name}-render.exr"));
        let size = ["--width", "160", "--height", "120", "--spp", "3"];
        render(scene, &png, &[&size[..], &["--backend", "cpu"]].concat());
        render(
            scene,
            &exr,
            &[
                &size[..],
                &["--backend", "cpu", "--aov", "depth,normal,steps"],
            ]
            .concat(),
        );
        assert_same_image(&shot, &png);
        assert_same_image(&shot.with_extension("exr"), &exr);
        assert!(psnr(&shot, &png) >= 40.0);
    }
}

#[test]
fn gpu_backend_screenshot_equals_gpu_render() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let shot = dir.path().join("view.png");
    let size = ["--width", "48", "--height", "36", "--spp", "2"];
    let mut args = size.to_vec();
    args.extend([
        "--backend",
        "gpu",
        "--screenshot",
        shot.to_str().expect("utf-8"),
    ]);
    let out = run(x.view(&args), "hytrace view --backend gpu");
    assert_ok(&out, "hytrace view --backend gpu");
    let png = dir.path().join("render.png");
    render(None, &png, &[&size[..], &["--backend", "gpu"]].concat());
    assert_same_image(&shot, &png);
}

/// What the window shows of the refined image, below the heads-up band, is what `render`
/// writes: on the GPU the sums are tone-mapped where the render kernel left them (the shown
/// frame is never read back; the device may round a code on a boundary the other way), on the
/// CPU the host's pixels are drawn unchanged.
#[test]
fn the_window_shows_what_render_writes_on_either_backend() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let size = ["--width", "160", "--height", "120", "--spp", "2"];
    for backend in ["gpu", "cpu"] {
        let shot = dir.path().join(format!("window-{backend}.png"));
        let script = dir.path().join(format!("window-{backend}.txt"));
        std::fs::write(
            &script,
            format!("converge\nwindow-shot {}\nquit\n", shot.display()),
        )
        .expect("write script");
        let mut args = size.to_vec();
        args.extend([
            "--backend",
            backend,
            "--script",
            script.to_str().expect("utf-8"),
        ]);
        let what = format!("hytrace view --backend {backend}");
        let out = run(x.view(&args), &what);
        assert_ok(&out, &what);
        let png = dir.path().join(format!("render-{backend}.png"));
        render(None, &png, &[&size[..], &["--backend", backend]].concat());
        let window = image::open(&shot).expect("window shot").to_rgb8();
        let rendered = image::open(&png).expect("render").to_rgb8();
        assert_eq!(window.dimensions(), rendered.dimensions());
        // the band holds at most six lines of 10 rows at this width
        let below = |img: &image::RgbImage| img.as_raw()[(70 * 160 * 3) as usize..].to_vec();
        let (a, b) = (below(&window), below(&rendered));
        let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
        let most = a
            .iter()
            .zip(&b)
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap_or(0);
        if backend == "cpu" {
            assert_eq!(differ, 0, "the CPU's picture is drawn unchanged");
        }
        assert!(
            most <= 1 && differ * 1000 <= a.len(),
            "{backend}: {differ} of {} codes differ from render's, by up to {most}",
            a.len()
        );
        // and the band is there: its rows are darker than render's
        let top = |img: &image::RgbImage| -> u64 {
            img.as_raw()[..(4 * 160 * 3) as usize]
                .iter()
                .map(|&c| c as u64)
                .sum()
        };
        assert!(
            top(&window) < top(&rendered),
            "{backend}: the heads-up band darkens the top"
        );
    }
}

/// The screenshot `shot` of a moved camera equals `render` of the showcase from the camera the
/// viewer printed, at 160×120 and 2 samples on the CPU.
fn assert_printed_camera_renders_shot(printed: &str, shot: &Path, dir: &Path, what: &str) {
    let moved = with_camera(SHOWCASE, printed);
    assert_ne!(
        scene_camera(&moved).trim(),
        scene_camera(SHOWCASE).trim(),
        "{what} moved the camera"
    );
    let scene = dir.join("moved.ron");
    std::fs::write(&scene, moved).expect("write scene");
    let png = dir.join("render.png");
    render(
        Some(&scene),
        &png,
        &[
            "--width",
            "160",
            "--height",
            "120",
            "--spp",
            "2",
            "--backend",
            "cpu",
        ],
    );
    assert_same_image(shot, &png);
}

#[test]
fn scripted_orbit_moves_the_camera_that_c_prints() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let shot = dir.path().join("orbit.png");
    let script = dir.path().join("orbit.txt");
    std::fs::write(
        &script,
        format!(
            "wait 0.2\n\
             drag 80 60 130 75\n\
             scroll 1.5\n\
             drag 80 60 95 50 shift\n\
             key w\n\
             converge\n\
             print-camera\n\
             screenshot {}\n\
             quit\n",
            shot.display()
        ),
    )
    .expect("write script");
    let args = scripted("160", "120", "2", &script);
    let out = run(x.view(&args), "scripted orbit");
    assert_ok(&out, "scripted orbit");
    let printed = String::from_utf8_lossy(&out.stdout);
    assert_printed_camera_renders_shot(&printed, &shot, dir.path(), "the script");
}

#[test]
fn real_input_events_orbit_print_and_screenshot() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let child = x
        .view(&[
            "--width",
            "160",
            "--height",
            "120",
            "--spp",
            "2",
            "--backend",
            "cpu",
            "--screenshot-dir",
            dir.path().to_str().expect("utf-8"),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn hytrace view");
    let id = x.xdotool(&["search", "--sync", "--name", "hytrace"]);
    let id = id.lines().next().expect("the viewer's window").to_string();
    x.xdotool(&["windowfocus", "--sync", &id]);
    // a hand's drag: press, a few moves with time for preview frames, release
    x.xdotool(&[
        "mousemove",
        "--window",
        &id,
        "80",
        "60",
        "mousedown",
        "1",
        "sleep",
        "0.1",
        "mousemove",
        "--window",
        &id,
        "100",
        "62",
        "sleep",
        "0.1",
        "mousemove",
        "--window",
        &id,
        "125",
        "70",
        "sleep",
        "0.1",
        "mouseup",
        "1",
    ]);
    x.xdotool(&["sleep", "0.3", "key", "c", "sleep", "0.2", "key", "p"]);
    let shot = dir.path().join("hytrace-view-001.png");
    let deadline = Instant::now() + VIEWER_TIMEOUT;
    while !shot.exists() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(100));
    }
    // the file appears when written in full: give the writer a moment before quitting
    std::thread::sleep(Duration::from_millis(300));
    x.xdotool(&["key", "Escape"]);
    let out = finish(child, "viewer under xdotool");
    assert_ok(&out, "viewer under xdotool");
    assert!(shot.exists(), "P wrote no screenshot");
    let printed = String::from_utf8_lossy(&out.stdout);
    assert_printed_camera_renders_shot(&printed, &shot, dir.path(), "the drag");
}

/// Waits until `path` exists (the viewer's script wrote it).
fn wait_for(path: &Path, child: &mut Child) {
    let deadline = Instant::now() + VIEWER_TIMEOUT;
    while !path.exists() {
        if let Some(status) = child.try_wait().expect("wait") {
            panic!(
                "the viewer exited ({status}) before writing {}",
                path.display()
            );
        }
        assert!(
            Instant::now() < deadline,
            "{} never appeared",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(200));
}

/// Saves a file as editors do: a new file moved over the old one.
fn save(path: &Path, text: &str) {
    let tmp = path.with_extension("saving");
    std::fs::write(&tmp, text).expect("write");
    std::fs::rename(&tmp, path).expect("rename");
}

#[test]
fn hot_reload_follows_edits_and_survives_a_broken_one() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = dir.path().join("scene.ron");
    let original = SHOWCASE.to_string();
    // the showcase's first material, recoloured
    let marker = "color: (";
    let at = original.find(marker).expect("a material colour") + marker.len();
    let end = at + original[at..].find(')').expect("colour end");
    let recoloured = format!("{}0.1, 0.9, 0.2{}", &original[..at], &original[end..]);
    assert_ne!(recoloured, original);
    // a typing slip in the same colour: a missing comma, on a known line
    let broken_line = original[..at].lines().count();
    let broken = format!("{}0.1, 0.9 0.2{}", &original[..at], &original[end..]);
    std::fs::write(&scene, &original).expect("write scene");
    let shots: Vec<PathBuf> = ["a.png", "b.png", "c.png", "d.png"]
        .iter()
        .map(|n| dir.path().join(n))
        .collect();
    let script = dir.path().join("reload.txt");
    std::fs::write(
        &script,
        format!(
            "converge\nscreenshot {}\nwait-reload\nconverge\nscreenshot {}\nwait-reload\n\
             wait 0.3\nwindow-shot {}\nwait-reload\nconverge\nscreenshot {}\nquit\n",
            shots[0].display(),
            shots[1].display(),
            shots[2].display(),
            shots[3].display()
        ),
    )
    .expect("write script");
    let mut child = x.spawn_scripted(&scene, "120", "90", &script);
    wait_for(&shots[0], &mut child);
    save(&scene, &recoloured);
    wait_for(&shots[1], &mut child);
    save(&scene, &broken);
    wait_for(&shots[2], &mut child);
    save(&scene, &recoloured);
    let out = finish(child, "hot reload");
    assert_ok(&out, "hot reload");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let place = format!("scene.ron:{broken_line}:");
    assert!(
        stderr.lines().any(|l| l.contains(&place)),
        "the reload error names the file and line ({place}):\n{stderr}"
    );
    // the recolour changed the picture; the fix brought the recoloured picture back
    assert!(
        std::fs::read(&shots[0]).expect("a") != std::fs::read(&shots[1]).expect("b"),
        "the colour edit changed the picture"
    );
    let scene_b = dir.path().join("render-b.ron");
    std::fs::write(&scene_b, &recoloured).expect("write");
    let png = dir.path().join("render-b.png");
    let size = cpu_options("120", "90", "1");
    render(Some(&scene_b), &png, &size);
    assert_same_image(&shots[1], &png);
    assert_same_image(&shots[3], &png);
    // while broken, the window showed the error in the heads-up band: the error colour
    let shown = image::open(&shots[2]).expect("window shot").to_rgb8();
    let error_pixels = shown
        .enumerate_pixels()
        .filter(|(_, _, p)| p.0 == [255, 120, 100])
        .count();
    assert!(
        error_pixels > 20,
        "the window shows the error ({error_pixels} pixels)"
    );
}

/// One line on stderr, a non-zero exit, no panic.
fn assert_one_line_failure(out: &Output, what: &str, says: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{what}: exit status {}", out.status);
    assert!(!stderr.contains("panicked"), "{what} panicked:\n{stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{what}: one line, got:\n{stderr}");
    assert!(
        lines[0].starts_with("error: ") && lines[0].to_lowercase().contains(&says.to_lowercase()),
        "{what}: {stderr}"
    );
}

#[test]
fn missing_display_is_one_line() {
    let mut c = hytrace();
    c.args(["view", "--frames", "1"])
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("WAYLAND_SOCKET");
    let out = run(c, "view without a display");
    assert_one_line_failure(&out, "view without a display", "no display");
}

#[test]
fn missing_vulkan_driver_is_one_line() {
    let x = Xvfb::start();
    for backend in ["auto", "cpu", "gpu"] {
        let mut c = x.view(&["--frames", "1", "--width", "64", "--height", "48"]);
        c.args(["--backend", backend])
            .env("VK_ICD_FILENAMES", "/nonexistent")
            .env("VK_DRIVER_FILES", "/nonexistent");
        let out = run(c, "view without a Vulkan driver");
        assert_one_line_failure(&out, &format!("--backend {backend}"), "Vulkan");
    }
}

#[test]
fn bad_scene_and_script_are_one_line() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = dir.path().join("bad.ron");
    std::fs::write(&scene, "Scene(\n  image: (width: 10,\n").expect("write");
    let out = run(x.view(&[scene.to_str().expect("utf-8")]), "bad scene");
    assert_one_line_failure(&out, "bad scene", "bad.ron:");
    let script = dir.path().join("bad.txt");
    std::fs::write(&script, "wait 1\nfly 3\n").expect("write");
    let out = run(
        x.view(&["--script", script.to_str().expect("utf-8")]),
        "bad script",
    );
    assert_one_line_failure(&out, "bad script", "bad.txt:2");
    // a reload the built-in showcase can never have: refused, not waited for forever
    std::fs::write(&script, "wait-reload\n").expect("write");
    let out = run(
        x.view(&["--script", script.to_str().expect("utf-8")]),
        "wait-reload without a file",
    );
    assert_one_line_failure(&out, "wait-reload without a file", "no file to watch");
}

/// A screenshot asked for but not written, the window closed first by `--frames`, is an
/// error, not a silent success.
#[test]
fn a_screenshot_the_window_closed_before_is_an_error() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let shot = dir.path().join("never.png");
    // one frame: a first frame never has 1,024 samples
    let mut args = cpu_options("64", "48", "1024").to_vec();
    args.extend([
        "--frames",
        "1",
        "--screenshot",
        shot.to_str().expect("utf-8"),
    ]);
    let out = run(x.view(&args), "--frames before the screenshot");
    assert_one_line_failure(&out, "--frames before the screenshot", "not written");
    assert!(!shot.exists());
}

#[test]
fn the_view_key_shows_the_debug_views_render_draws() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let views = ["normals", "depth"];
    let shots: Vec<PathBuf> = views
        .iter()
        .map(|v| dir.path().join(format!("{v}.png")))
        .collect();
    let script = dir.path().join("views.txt");
    std::fs::write(
        &script,
        format!(
            "key v\nconverge\nscreenshot {}\nkey v\nconverge\nscreenshot {}\nquit\n",
            shots[0].display(),
            shots[1].display()
        ),
    )
    .expect("write script");
    let size = cpu_options("96", "72", "2");
    let mut args = size.to_vec();
    args.extend(["--script", script.to_str().expect("utf-8")]);
    let out = run(x.view(&args), "view keys");
    assert_ok(&out, "view keys");
    for (view, shot) in views.iter().zip(&shots) {
        let png = dir.path().join(format!("render-{view}.png"));
        render(None, &png, &[&size[..], &["--view", view]].concat());
        assert_same_image(shot, &png);
    }
}

#[test]
fn a_resized_window_refines_to_render_at_its_new_size() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let shot = dir.path().join("resized.png");
    let script = dir.path().join("resize.txt");
    // the wait leaves time for the resize below to arrive before the screenshot is taken
    std::fs::write(
        &script,
        format!("wait 2\nconverge\nscreenshot {}\nquit\n", shot.display()),
    )
    .expect("write script");
    let child = x
        .view(&scripted("160", "120", "1", &script))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn hytrace view");
    let id = x.xdotool(&["search", "--sync", "--name", "hytrace"]);
    let id = id.lines().next().expect("the viewer's window").to_string();
    x.xdotool(&["windowsize", "--sync", &id, "200", "150"]);
    let out = finish(child, "resized viewer");
    assert_ok(&out, "resized viewer");
    let png = dir.path().join("render.png");
    render(
        None,
        &png,
        &[
            "--width",
            "200",
            "--height",
            "150",
            "--spp",
            "1",
            "--backend",
            "cpu",
        ],
    );
    assert_same_image(&shot, &png);
}

#[test]
fn a_click_on_a_surface_makes_it_the_pivot() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let shot = dir.path().join("picked.png");
    let script = dir.path().join("pick.txt");
    // the lower middle of the showcase is ground or an object, never sky
    std::fs::write(
        &script,
        format!(
            "wait 0.3\nclick 80 100\nwait 0.5\nconverge\nprint-camera\nscreenshot {}\nquit\n",
            shot.display()
        ),
    )
    .expect("write script");
    let args = scripted("160", "120", "2", &script);
    let out = run(x.view(&args), "pick");
    assert_ok(&out, "pick");
    let printed = String::from_utf8_lossy(&out.stdout);
    let look_at = |camera: &str| {
        let at = camera.find("look_at:").expect("look_at") + "look_at:".len();
        let text = &camera[at..camera[at..].find(')').expect("end") + at];
        text.trim()
            .trim_start_matches('(')
            .split(',')
            .map(|v| v.trim().parse::<f32>().expect("a number"))
            .collect::<Vec<f32>>()
    };
    let before = look_at(scene_camera(SHOWCASE));
    let after = look_at(&printed);
    let moved = before
        .iter()
        .zip(&after)
        .map(|(a, b)| (a - b).abs())
        .sum::<f32>();
    assert!(
        moved > 0.1,
        "the pivot moved to the hit: {before:?} → {after:?}"
    );
    assert_printed_camera_renders_shot(&printed, &shot, dir.path(), "the click");
}

/// The first picture is the scene's camera bit for bit, also where 2·atan(tan(fov/2)) does not
/// round-trip (fov 47.1) and `up` is tilted, so the screenshot is `render`'s; and `--frames N`
/// closes the window once the image has converged, with fewer than N frames shown (it waited
/// for frames that never came).
#[test]
fn the_first_picture_is_render_s_and_frames_end_at_convergence() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let camera = scene_camera(SHOWCASE);
    let tilted = SHOWCASE.replace(
        camera,
        "    camera: Perspective(position: (0, 4.5, 12), look_at: (0, 0.6, -1.5), \
         up: (0.3, 1, 0), fov: 47.1),",
    );
    let scene = dir.path().join("tilted.ron");
    std::fs::write(&scene, &tilted).expect("write scene");
    let shot = dir.path().join("view.png");
    let size = cpu_options("160", "120", "2");
    let mut args = vec![scene.to_str().expect("utf-8")];
    args.extend(size);
    args.extend(["--screenshot", shot.to_str().expect("utf-8")]);
    let out = run(x.view(&args), "screenshot of a tilted camera");
    assert_ok(&out, "screenshot of a tilted camera");
    let png = dir.path().join("render.png");
    render(Some(&scene), &png, &size);
    assert_same_image(&shot, &png);

    let mut args = vec![scene.to_str().expect("utf-8")];
    args.extend(size);
    args.extend(["--frames", "1000"]);
    let out = run(x.view(&args), "--frames beyond convergence");
    assert_ok(&out, "--frames beyond convergence");
}

/// Hot reload follows the mesh files the scene names now: after the scene swaps one mesh file
/// for another, an edit of the new one reloads; a scene naming a mesh file not written yet
/// reloads when the file appears.
#[test]
fn hot_reload_watches_the_mesh_files_the_scene_names_now() {
    let x = Xvfb::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let quad =
        |z: f32| format!("v -1 -1 {z}\nv 1 -1 {z}\nv 1 1 {z}\nv -1 1 {z}\nf 1 2 3\nf 1 3 4\n");
    std::fs::write(dir.path().join("a.obj"), quad(0.0)).expect("write a.obj");
    std::fs::write(dir.path().join("b.obj"), quad(0.0)).expect("write b.obj");
    let scene_with = |mesh: &str| {
        format!(
            "Scene(\n    camera: Perspective(position: (0, 0, 4), look_at: (0, 0, 0), fov: 40),\n    \
             lights: [Ambient(intensity: 1)],\n    \
             materials: {{\"m\": (color: (0.9, 0.3, 0.1))}},\n    \
             objects: [(mesh: \"{mesh}\", material: \"m\")],\n)\n"
        )
    };
    let scene = dir.path().join("scene.ron");
    std::fs::write(&scene, scene_with("a.obj")).expect("write scene");
    let shots: Vec<PathBuf> = ["1.png", "2.png", "3.png", "4.png"]
        .iter()
        .map(|n| dir.path().join(n))
        .collect();
    let script = dir.path().join("reload.txt");
    // after the third picture two reloads come: the one that fails, then the good one
    let shot = |i: usize| shots[i].display().to_string();
    let steps = format!(
        "converge\nscreenshot {}\nwait-reload\nconverge\nscreenshot {}\nwait-reload\n\
         converge\nscreenshot {}\nwait-reload\nwait-reload\nconverge\nscreenshot {}\nquit\n",
        shot(0),
        shot(1),
        shot(2),
        shot(3)
    );
    std::fs::write(&script, steps).expect("write script");
    let mut child = x.spawn_scripted(&scene, "64", "48", &script);
    wait_for(&shots[0], &mut child);
    // the scene swaps a.obj for b.obj (one mesh file before and after)
    save(&scene, &scene_with("b.obj"));
    wait_for(&shots[1], &mut child);
    // an edit of b.obj: the quad moves back, smaller on screen
    save(&dir.path().join("b.obj"), &quad(-3.0));
    wait_for(&shots[2], &mut child);
    // a mesh file not written yet: an error, then the file appears
    save(&scene, &scene_with("later.obj"));
    std::thread::sleep(Duration::from_millis(600));
    save(&dir.path().join("later.obj"), &quad(-1.0));
    wait_for(&shots[3], &mut child);
    let out = finish(child, "mesh hot reload");
    assert_ok(&out, "mesh hot reload");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("later.obj"),
        "the missing mesh is reported:\n{stderr}"
    );
    let bytes = |p: &PathBuf| std::fs::read(p).expect("screenshot");
    assert_ne!(
        bytes(&shots[1]),
        bytes(&shots[2]),
        "the edit of b.obj reloaded"
    );
    assert_ne!(
        bytes(&shots[2]),
        bytes(&shots[3]),
        "later.obj's arrival reloaded"
    );
    let now = dir.path().join("now.png");
    render(Some(&scene), &now, &cpu_options("64", "48", "1"));
    assert_same_image(&shots[3], &now);
}

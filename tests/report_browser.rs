//! The report pages of `compare` and `validate --html`, opened in a real browser: headless
//! Chromium driven through ChromeDriver's WebDriver protocol. The pictures load, the swipe
//! control, the flip button and the wheel zoom change what the viewer shows, the pixel values
//! appear under the cursor, a disagreeing ray's link takes the viewer to its pixel, and the
//! page logs no error.
//!
//! Chromium and ChromeDriver are Debian's `chromium` and `chromium-driver`, installed by
//! `scripts/setup.sh`; when either is missing the tests fail and say so (they never skip).
#![cfg(feature = "embree")]

use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const CHROMIUM: &str = "/usr/bin/chromium";
const CHROMEDRIVER: &str = "/usr/bin/chromedriver";

/// How long a page may take to load its pictures.
const LOAD_TIMEOUT: Duration = Duration::from_secs(30);

fn hytrace() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hytrace"))
}

fn scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/scenes")
        .join(name)
}

fn run(cmd: &mut Command) {
    let out = cmd.output().expect("hytrace runs");
    assert!(
        out.status.success(),
        "{cmd:?} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A ChromeDriver on a port of its own with one headless Chromium session; both end on drop.
struct Browser {
    driver: Child,
    base: String,
    session: String,
    _profile: tempfile::TempDir,
}

impl Browser {
    fn start() -> Browser {
        for tool in [CHROMIUM, CHROMEDRIVER] {
            assert!(
                Path::new(tool).exists(),
                "{tool} is missing: run scripts/setup.sh (it installs Debian's chromium and chromium-driver)"
            );
        }
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("a free port")
            .port();
        let driver = Command::new(CHROMEDRIVER)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver starts");
        let base = format!("http://127.0.0.1:{port}");
        let start = Instant::now();
        while ureq::get(&format!("{base}/status")).call().is_err() {
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "chromedriver did not answer"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        let profile = tempfile::tempdir().unwrap();
        // The flags the machine notes give for Chromium on a closed network, as root.
        let args = [
            "--headless=new".to_string(),
            "--no-sandbox".into(),
            "--disable-gpu".into(),
            "--disable-quic".into(),
            "--no-first-run".into(),
            "--disable-background-networking".into(),
            "--disable-component-update".into(),
            "--disable-sync".into(),
            "--window-size=1200,900".into(),
            "--force-device-scale-factor=1".into(),
            format!("--user-data-dir={}", profile.path().display()),
        ];
        let caps = json!({"capabilities": {"alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {"binary": CHROMIUM, "args": args},
            "goog:loggingPrefs": {"browser": "ALL"},
        }}});
        let mut browser = Browser {
            driver,
            base,
            session: String::new(),
            _profile: profile,
        };
        let v = browser.post("/session", caps);
        browser.session = v["sessionId"].as_str().expect("a session").to_string();
        browser
    }

    fn url(&self, path: &str) -> String {
        if path == "/session" {
            format!("{}/session", self.base)
        } else {
            format!("{}/session/{}{path}", self.base, self.session)
        }
    }

    fn answer(r: Result<ureq::Response, ureq::Error>, what: &str) -> Value {
        match r {
            Ok(resp) => resp.into_json::<Value>().expect("JSON")["value"].clone(),
            Err(ureq::Error::Status(code, resp)) => {
                panic!(
                    "{what}: HTTP {code}: {}",
                    resp.into_string().unwrap_or_default()
                )
            }
            Err(e) => panic!("{what}: {e}"),
        }
    }

    fn post(&self, path: &str, body: Value) -> Value {
        Self::answer(ureq::post(&self.url(path)).send_json(body), path)
    }

    fn get(&self, path: &str) -> Value {
        Self::answer(ureq::get(&self.url(path)).call(), path)
    }

    fn open(&self, page: &Path) {
        self.post("/url", json!({"url": format!("file://{}", page.display())}));
        let start = Instant::now();
        while self.js("return document.body.dataset.loaded === 'true'") != json!(true) {
            assert!(
                start.elapsed() < LOAD_TIMEOUT,
                "{}: the pictures did not load; page errors: {}",
                page.display(),
                self.js("return window.reportErrors")
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn js(&self, script: &str) -> Value {
        self.post("/execute/sync", json!({"script": script, "args": []}))
    }

    fn element(&self, css: &str) -> String {
        let v = self.post("/element", json!({"using": "css selector", "value": css}));
        v.as_object()
            .and_then(|o| o.values().next())
            .and_then(Value::as_str)
            .unwrap_or_else(|| panic!("no element {css}"))
            .to_string()
    }

    fn click(&self, css: &str) {
        let id = self.element(css);
        self.post(&format!("/element/{id}/click"), json!({}));
    }

    /// A screenshot of one element, as the browser shows it.
    fn shot(&self, css: &str) -> image::RgbImage {
        use base64::Engine;
        let id = self.element(css);
        let png = self.get(&format!("/element/{id}/screenshot"));
        let bytes = base64::engine::general_purpose::STANDARD
            .decode(png.as_str().expect("base64"))
            .expect("a PNG");
        image::load_from_memory(&bytes).unwrap().into_rgb8()
    }

    /// Real pointer input: press at `from`, move to `to`, release; offsets from the element's
    /// centre, in CSS pixels.
    fn drag(&self, css: &str, from: (i64, i64), to: (i64, i64)) {
        let id = self.element(css);
        let origin = json!({"element-6066-11e4-a52e-4f735466cecf": id});
        self.post(
            "/actions",
            json!({"actions": [{"type": "pointer", "id": "mouse", "parameters": {"pointerType": "mouse"},
                "actions": [
                    {"type": "pointerMove", "origin": origin, "x": from.0, "y": from.1, "duration": 0},
                    {"type": "pointerDown", "button": 0},
                    {"type": "pointerMove", "origin": origin, "x": (from.0 + to.0) / 2, "y": (from.1 + to.1) / 2, "duration": 50},
                    {"type": "pointerMove", "origin": origin, "x": to.0, "y": to.1, "duration": 50},
                    {"type": "pointerUp", "button": 0},
                ]}]}),
        );
        self.post("/actions", json!({"actions": []}));
    }

    /// Turns the mouse wheel over the element's centre (negative: away from the user, zoom in).
    fn wheel(&self, css: &str, delta_y: i64) {
        let id = self.element(css);
        let origin = json!({"element-6066-11e4-a52e-4f735466cecf": id});
        self.post(
            "/actions",
            json!({"actions": [{"type": "wheel", "id": "wheel", "actions": [
                {"type": "scroll", "origin": origin, "x": 0, "y": 0, "deltaX": 0, "deltaY": delta_y, "duration": 0},
            ]}]}),
        );
    }

    /// The browser's console entries at level SEVERE, and the errors the page recorded.
    fn errors(&self) -> Vec<String> {
        let mut out: Vec<String> = self
            .post("/se/log", json!({"type": "browser"}))
            .as_array()
            .cloned()
            .unwrap_or_default()
            .into_iter()
            .filter(|e| e["level"] == "SEVERE")
            .map(|e| e["message"].to_string())
            .collect();
        if let Some(page) = self.js("return window.reportErrors").as_array() {
            out.extend(page.iter().map(Value::to_string));
        }
        out
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        if !self.session.is_empty() {
            let _ = ureq::delete(&format!("{}/session/{}", self.base, self.session)).call();
        }
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

/// Mean absolute difference of two equally sized pictures over the columns [x0, x1) as
/// fractions of the width, 0..255.
fn band_difference(a: &image::RgbImage, b: &image::RgbImage, x0: f32, x1: f32) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let (w, h) = a.dimensions();
    let (c0, c1) = ((x0 * w as f32) as u32, (x1 * w as f32) as u32);
    let mut sum = 0u64;
    let mut n = 0u64;
    for y in 0..h {
        for x in c0..c1 {
            let (p, q) = (a.get_pixel(x, y).0, b.get_pixel(x, y).0);
            sum += (0..3).map(|c| p[c].abs_diff(q[c]) as u64).sum::<u64>();
            n += 3;
        }
    }
    sum as f64 / n.max(1) as f64
}

#[test]
fn the_compare_report_swipes_flips_zooms_and_reads_pixels_in_a_browser() {
    let dir = tempfile::tempdir().unwrap();
    run(hytrace()
        .arg("compare")
        .arg(scene("csg.ron"))
        .args(["--width", "160", "--height", "120", "--gpu", "never", "-o"])
        .arg(dir.path()));
    let page = dir.path().join("index.html");
    let browser = Browser::start();
    browser.open(&page);

    // every picture decoded at its size: the two renders, a difference and a FLIP map
    let sizes = browser.js(
        "return pictures.map(p => [p.name, p.img.complete, p.img.naturalWidth === p.width && p.img.naturalHeight === p.height])",
    );
    let sizes = sizes.as_array().unwrap();
    let names: Vec<&str> = sizes.iter().map(|s| s[0].as_str().unwrap()).collect();
    assert_eq!(
        names,
        ["cpu", "embree", "diff-cpu-embree", "flip-cpu-embree"]
    );
    assert!(
        sizes
            .iter()
            .all(|s| s[1] == json!(true) && s[2] == json!(true)),
        "{sizes:?}"
    );
    // the metrics table has the pair with a FLIP figure
    let table = browser.js("return document.querySelector('tr.pair').textContent");
    assert!(table.as_str().unwrap().contains("embree vs cpu"), "{table}");

    // left the render, right the difference map: unlike pictures, so every control shows
    browser.click("#image-b option[value='2']");
    let split = browser.shot("#view");
    // the swipe slider dragged to its right end: the render everywhere
    browser.drag("#swipe", (-85, 0), (95, 0));
    let swiped = browser.shot("#view");
    assert_eq!(
        browser.js("return document.getElementById('swipe').value"),
        json!("1000")
    );
    assert!(
        band_difference(&split, &swiped, 0.05, 0.45) < 1.0,
        "the left half changed on swiping right"
    );
    assert!(
        band_difference(&split, &swiped, 0.55, 0.95) > 10.0,
        "swiping did not change the right half"
    );
    // flip: the right picture everywhere
    browser.click("#flip");
    let flipped = browser.shot("#view");
    assert!(
        band_difference(&swiped, &flipped, 0.05, 0.45) > 10.0,
        "flip did not change the view"
    );
    browser.click("#flip");
    // dragging the split line on the picture itself moves it back to the middle
    let width = browser
        .js("return document.getElementById('view').getBoundingClientRect().width")
        .as_f64()
        .unwrap() as i64;
    browser.drag("#view", (width / 2 - 1, 0), (0, 0));
    let split_again = browser.js("return state.split").as_f64().unwrap();
    assert!((split_again - 0.5).abs() < 0.02, "split {split_again}");

    // the wheel zooms in, and the read-out names the pixel and both pictures' values there
    let before = browser.js("return state.zoom").as_f64().unwrap();
    browser.wheel("#view", -1500);
    let after = browser.js("return state.zoom").as_f64().unwrap();
    assert!(after > 4.0 * before, "zoom {before} → {after}");
    browser.drag("#view", (10, 10), (12, 10));
    let readout = browser.js("return document.getElementById('readout').textContent");
    let readout = readout.as_str().unwrap();
    assert!(
        readout.contains("pixel (")
            && readout.contains("cpu (")
            && readout.contains("diff-cpu-embree ("),
        "{readout}"
    );
    let errors = browser.errors();
    assert!(errors.is_empty(), "the page logged errors: {errors:?}");
}

#[test]
fn the_validation_report_links_each_disagreeing_ray_to_its_pixel() {
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("validate.html");
    // At this grid csg.ron, its composites meshed, has rays that disagree at silhouettes
    // (within the thresholds; the certified referee agrees with our tracer on all of them).
    run(hytrace()
        .arg("validate")
        .arg(scene("csg.ron"))
        .args([
            "--width", "120", "--height", "80", "--random", "2000", "--meshed", "--html",
        ])
        .arg(&page));
    let browser = Browser::start();
    browser.open(&page);
    let headings =
        browser.js("return [...document.querySelectorAll('h2')].map(h => h.textContent)");
    let headings: Vec<&str> = headings
        .as_array()
        .unwrap()
        .iter()
        .map(|h| h.as_str().unwrap())
        .collect();
    for wanted in [
        "Verdict",
        "Rays per object kind",
        "Shadow rays",
        "Objects",
        "Mismatch image",
    ] {
        assert!(headings.contains(&wanted), "no {wanted} in {headings:?}");
    }
    let links = browser.js("return document.querySelectorAll('.pixels a').length");
    assert!(links.as_u64().unwrap() > 0, "no disagreeing pixel listed");
    let (x, y) = {
        let v = browser.js("const a = document.querySelector('.pixels a'); return [Number(a.dataset.x), Number(a.dataset.y)]");
        (v[0].as_u64().unwrap(), v[1].as_u64().unwrap())
    };
    browser.click(".pixels a");
    assert_eq!(browser.js("return state.zoom"), json!(16));
    let readout = browser.js("return document.getElementById('readout').textContent");
    assert!(
        readout
            .as_str()
            .unwrap()
            .starts_with(&format!("pixel ({x}, {y})")),
        "{readout}"
    );
    // the marked pixel sits in the middle of the view
    let centre = browser.js(
        "const c = document.getElementById('view'); return [(c.width / 2 - state.panX) / state.zoom, (c.height / 2 - state.panY) / state.zoom]",
    );
    assert_eq!(centre[0].as_f64().unwrap().floor() as u64, x);
    assert_eq!(centre[1].as_f64().unwrap().floor() as u64, y);
    let errors = browser.errors();
    assert!(errors.is_empty(), "the page logged errors: {errors:?}");
}

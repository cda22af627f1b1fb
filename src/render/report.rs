//! Comparison reports people browse: one self-contained HTML page (no network; its pictures
//! embedded as PNG data) with a viewer that swipes and flips between any two pictures, zooms and
//! pans them together down to single pixels and shows the pixel values under the cursor, plus
//! tables, a colour legend and links that take the viewer to a pixel.
//!
//! The page is a template (`report.html`, its CSS and script inline) and the report's data as
//! one JSON object; the pictures are embedded rather than linked because a page opened from
//! disk may not read the pixels of pictures beside it (a `file:` page's canvas is tainted by
//! them), and the pixel values under the cursor need those pixels.

use base64::Engine;
use image::RgbImage;
use serde::Serialize;
use std::io::Cursor;

/// The page's template: `/*REPORT-DATA*/` is replaced by the report's JSON.
const TEMPLATE: &str = include_str!("report.html");
const DATA_SLOT: &str = "/*REPORT-DATA*/";

/// A report page under construction.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Report {
    /// The page's title.
    pub title: String,
    /// Facts shown under the title: (what, value).
    pub facts: Vec<(String, String)>,
    /// The pictures, in the order the viewer lists them.
    pub images: Vec<Picture>,
    /// Which two pictures the viewer starts with (indices into `images`).
    pub initial: (usize, usize),
    /// Tables, each under its heading.
    pub tables: Vec<Table>,
    /// Colour legends: (colour, meaning) under a heading.
    pub legends: Vec<Legend>,
    /// Lists of pixels, each entry a link that shows its pixel in the viewer.
    pub pixel_lists: Vec<PixelList>,
    /// Lines of notes.
    pub notes: Vec<String>,
}

/// One picture of the report.
#[derive(Debug, Clone, Serialize)]
pub struct Picture {
    /// Short name (what the viewer's lists show).
    pub name: String,
    /// What it is, in words.
    pub description: String,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The PNG as a `data:` URL.
    pub src: String,
}

impl Picture {
    /// A picture, encoded as PNG for the page.
    pub fn new(name: &str, description: &str, image: &RgbImage) -> anyhow::Result<Self> {
        let mut png = Vec::new();
        image.write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)?;
        Ok(Picture {
            name: name.into(),
            description: description.into(),
            width: image.width(),
            height: image.height(),
            src: format!(
                "data:image/png;base64,{}",
                base64::engine::general_purpose::STANDARD.encode(&png)
            ),
        })
    }
}

/// A table: a header row and rows of cells; a row may name the two pictures it compares, and
/// clicking it shows that pair in the viewer.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Table {
    /// The heading above it.
    pub heading: String,
    /// Column names.
    pub header: Vec<String>,
    /// The rows.
    pub rows: Vec<Row>,
}

/// One row of a [`Table`].
#[derive(Debug, Clone, Default, Serialize)]
pub struct Row {
    /// The cells, as text.
    pub cells: Vec<String>,
    /// The pair of pictures (indices into the report's images) the row is about.
    pub pair: Option<(usize, usize)>,
    /// Whether the row marks a failure (shown in red).
    pub failed: bool,
}

/// A colour legend for a picture.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Legend {
    /// The heading above it.
    pub heading: String,
    /// (sRGB colour, meaning).
    pub entries: Vec<([u8; 3], String)>,
}

/// Pixels worth a look, each a link to it in the viewer.
#[derive(Debug, Clone, Default, Serialize)]
pub struct PixelList {
    /// The heading above the list.
    pub heading: String,
    /// The picture the viewer shows when a pixel is picked (index into the report's images).
    pub image: usize,
    /// The entries.
    pub pixels: Vec<PixelLink>,
    /// How many there were before the list was cut (the list holds at most a few hundred).
    pub total: usize,
}

/// One pixel of a [`PixelList`].
#[derive(Debug, Clone, Serialize)]
pub struct PixelLink {
    /// Column.
    pub x: u32,
    /// Row.
    pub y: u32,
    /// What is there, in words.
    pub label: String,
}

impl Report {
    /// The page, self-contained.
    pub fn html(&self) -> anyhow::Result<String> {
        // `</` would end the script element the JSON sits in.
        let data = serde_json::to_string(self)?.replace("</", "<\\/");
        anyhow::ensure!(
            TEMPLATE.matches(DATA_SLOT).count() == 1,
            "the report template has no single data slot"
        );
        Ok(TEMPLATE.replace(DATA_SLOT, &data))
    }

    /// Writes the page to `path`.
    pub fn write(&self, path: &std::path::Path) -> anyhow::Result<()> {
        use anyhow::Context;
        std::fs::write(path, self.html()?)
            .with_context(|| format!("{}: cannot write the report", path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_embeds_its_data_once_and_escapes_closing_tags() {
        let img = RgbImage::from_pixel(3, 2, image::Rgb([1, 2, 3]));
        let report = Report {
            title: "a </script> in a title".into(),
            images: vec![Picture::new("a", "first", &img).unwrap()],
            ..Default::default()
        };
        let html = report.html().unwrap();
        assert!(!html.contains(DATA_SLOT));
        assert!(html.contains("a <\\/script> in a title"));
        assert_eq!(
            html.matches("</script>").count(),
            html.matches("<script").count()
        );
        // the PNG decodes to the picture
        let src = &report.images[0].src;
        let png = base64::engine::general_purpose::STANDARD
            .decode(src.strip_prefix("data:image/png;base64,").unwrap())
            .unwrap();
        let back = image::load_from_memory(&png).unwrap().into_rgb8();
        assert_eq!(back, img);
    }
}

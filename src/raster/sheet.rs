//! Contact sheets: tiles laid out in rows with white gaps, each tile with a label strip above it
//! drawn in a built-in 5 x 7 pixel font (upper case, digits and a little punctuation; lower case
//! is drawn as upper case, anything else as a box). `locate --mark` and the flaws' contact sheet
//! draw through it.

use image::{Rgb, RgbImage};

/// Height of a tile's label strip, pixels.
pub const LABEL_PX: u32 = 11;
/// Horizontal advance of one character, pixels.
const ADVANCE: u32 = 6;

/// Rows of 7 glyph rows, 5 columns each ('#' = ink).
#[rustfmt::skip]
const GLYPHS: &[(char, [&str; 7])] = &[
    ('A', [" ### ", "#   #", "#   #", "#####", "#   #", "#   #", "#   #"]),
    ('B', ["#### ", "#   #", "#   #", "#### ", "#   #", "#   #", "#### "]),
    ('C', [" ### ", "#   #", "#    ", "#    ", "#    ", "#   #", " ### "]),
    ('D', ["#### ", "#   #", "#   #", "#   #", "#   #", "#   #", "#### "]),
    ('E', ["#####", "#    ", "#    ", "#### ", "#    ", "#    ", "#####"]),
    ('F', ["#####", "#    ", "#    ", "#### ", "#    ", "#    ", "#    "]),
    ('G', [" ### ", "#   #", "#    ", "# ###", "#   #", "#   #", " ####"]),
    ('H', ["#   #", "#   #", "#   #", "#####", "#   #", "#   #", "#   #"]),
    ('I', [" ### ", "  #  ", "  #  ", "  #  ", "  #  ", "  #  ", " ### "]),
    ('J', ["  ###", "   # ", "   # ", "   # ", "   # ", "#  # ", " ##  "]),
    ('K', ["#   #", "#  # ", "# #  ", "##   ", "# #  ", "#  # ", "#   #"]),
    ('L', ["#    ", "#    ", "#    ", "#    ", "#    ", "#    ", "#####"]),
    ('M', ["#   #", "## ##", "# # #", "# # #", "#   #", "#   #", "#   #"]),
    ('N', ["#   #", "#   #", "##  #", "# # #", "#  ##", "#   #", "#   #"]),
    ('O', [" ### ", "#   #", "#   #", "#   #", "#   #", "#   #", " ### "]),
    ('P', ["#### ", "#   #", "#   #", "#### ", "#    ", "#    ", "#    "]),
    ('Q', [" ### ", "#   #", "#   #", "#   #", "# # #", "#  # ", " ## #"]),
    ('R', ["#### ", "#   #", "#   #", "#### ", "# #  ", "#  # ", "#   #"]),
    ('S', [" ####", "#    ", "#    ", " ### ", "    #", "    #", "#### "]),
    ('T', ["#####", "  #  ", "  #  ", "  #  ", "  #  ", "  #  ", "  #  "]),
    ('U', ["#   #", "#   #", "#   #", "#   #", "#   #", "#   #", " ### "]),
    ('V', ["#   #", "#   #", "#   #", "#   #", "#   #", " # # ", "  #  "]),
    ('W', ["#   #", "#   #", "#   #", "# # #", "# # #", "# # #", " # # "]),
    ('X', ["#   #", "#   #", " # # ", "  #  ", " # # ", "#   #", "#   #"]),
    ('Y', ["#   #", "#   #", " # # ", "  #  ", "  #  ", "  #  ", "  #  "]),
    ('Z', ["#####", "    #", "   # ", "  #  ", " #   ", "#    ", "#####"]),
    ('0', [" ### ", "#   #", "#  ##", "# # #", "##  #", "#   #", " ### "]),
    ('1', ["  #  ", " ##  ", "  #  ", "  #  ", "  #  ", "  #  ", " ### "]),
    ('2', [" ### ", "#   #", "    #", "   # ", "  #  ", " #   ", "#####"]),
    ('3', ["#####", "   # ", "  #  ", "   # ", "    #", "#   #", " ### "]),
    ('4', ["   # ", "  ## ", " # # ", "#  # ", "#####", "   # ", "   # "]),
    ('5', ["#####", "#    ", "#### ", "    #", "    #", "#   #", " ### "]),
    ('6', ["  ## ", " #   ", "#    ", "#### ", "#   #", "#   #", " ### "]),
    ('7', ["#####", "    #", "   # ", "  #  ", " #   ", " #   ", " #   "]),
    ('8', [" ### ", "#   #", "#   #", " ### ", "#   #", "#   #", " ### "]),
    ('9', [" ### ", "#   #", "#   #", " ####", "    #", "   # ", " ##  "]),
    (' ', ["     ", "     ", "     ", "     ", "     ", "     ", "     "]),
    ('_', ["     ", "     ", "     ", "     ", "     ", "     ", "#####"]),
    ('-', ["     ", "     ", "     ", "#####", "     ", "     ", "     "]),
    ('+', ["     ", "  #  ", "  #  ", "#####", "  #  ", "  #  ", "     "]),
    ('.', ["     ", "     ", "     ", "     ", "     ", " ##  ", " ##  "]),
    (',', ["     ", "     ", "     ", "     ", " ##  ", "  #  ", " #   "]),
    (':', ["     ", " ##  ", " ##  ", "     ", " ##  ", " ##  ", "     "]),
    ('=', ["     ", "     ", "#####", "     ", "#####", "     ", "     "]),
    ('/', ["    #", "    #", "   # ", "  #  ", " #   ", "#    ", "#    "]),
    ('(', ["   # ", "  #  ", " #   ", " #   ", " #   ", "  #  ", "   # "]),
    (')', [" #   ", "  #  ", "   # ", "   # ", "   # ", "  #  ", " #   "]),
    ('#', [" # # ", " # # ", "#####", " # # ", "#####", " # # ", " # # "]),
];

fn glyph(c: char) -> [&'static str; 7] {
    let c = c.to_ascii_uppercase();
    GLYPHS.iter().find(|(g, _)| *g == c).map_or(
        [
            "#####", "#   #", "#   #", "#   #", "#   #", "#   #", "#####",
        ],
        |g| g.1,
    )
}

/// Draws `text` with its top-left corner at (x, y); what falls outside `img` is clipped.
pub fn draw_text(img: &mut RgbImage, x: u32, y: u32, text: &str, color: Rgb<u8>) {
    for (i, c) in text.chars().enumerate() {
        let x0 = x as u64 + i as u64 * u64::from(ADVANCE);
        for (dy, row) in glyph(c).iter().enumerate() {
            for (dx, ink) in row.bytes().enumerate() {
                let (px, py) = (x0 + dx as u64, u64::from(y) + dy as u64);
                if ink == b'#' && px < u64::from(img.width()) && py < u64::from(img.height()) {
                    img.put_pixel(px as u32, py as u32, color);
                }
            }
        }
    }
}

/// How many characters fit in `width` pixels.
pub fn chars_in(width: u32) -> usize {
    (width.saturating_sub(2) / ADVANCE) as usize
}

/// `tile` with a white strip of [`LABEL_PX`] per line above it holding `label` in black (lines
/// split at `\n`, each clipped to the tile's width).
pub fn labelled(tile: &RgbImage, label: &str) -> RgbImage {
    let lines: Vec<&str> = label.split('\n').collect();
    let strip = LABEL_PX * lines.len() as u32;
    let mut out = RgbImage::from_pixel(tile.width(), tile.height() + strip, Rgb([255; 3]));
    image::imageops::replace(&mut out, tile, 0, i64::from(strip));
    for (i, line) in lines.iter().enumerate() {
        draw_text(&mut out, 1, 2 + i as u32 * LABEL_PX, line, Rgb([0, 0, 0]));
    }
    out
}

/// Rows of tiles on white, `gap` pixels between tiles and around them; each cell is as large as
/// the largest tile.
pub fn sheet(rows: &[Vec<RgbImage>], gap: u32) -> RgbImage {
    let cell_w = rows.iter().flatten().map(|t| t.width()).max().unwrap_or(0);
    let cell_h = rows.iter().flatten().map(|t| t.height()).max().unwrap_or(0);
    let columns = rows.iter().map(|r| r.len()).max().unwrap_or(0) as u32;
    let mut out = RgbImage::from_pixel(
        columns * (cell_w + gap) + gap,
        rows.len() as u32 * (cell_h + gap) + gap,
        Rgb([255; 3]),
    );
    for (r, row) in rows.iter().enumerate() {
        for (c, tile) in row.iter().enumerate() {
            let x = gap + c as u32 * (cell_w + gap);
            let y = gap + r as u32 * (cell_h + gap);
            image::imageops::replace(&mut out, tile, i64::from(x), i64::from(y));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glyphs_are_five_by_seven_and_distinct() {
        for (c, rows) in GLYPHS {
            assert!(rows.iter().all(|r| r.len() == 5), "{c}");
        }
        for (i, a) in GLYPHS.iter().enumerate() {
            for b in &GLYPHS[i + 1..] {
                assert!(a.1 != b.1, "{} and {} look alike", a.0, b.0);
            }
        }
    }

    #[test]
    fn labels_draw_ink_above_the_tile_and_sheets_lay_tiles_out() {
        let tile = RgbImage::from_pixel(40, 20, Rgb([0, 128, 0]));
        let l = labelled(&tile, "post_top 12");
        assert_eq!(l.dimensions(), (40, 20 + LABEL_PX));
        let ink = (0..LABEL_PX)
            .flat_map(|y| (0..40).map(move |x| (x, y)))
            .filter(|&(x, y)| l.get_pixel(x, y).0 == [0, 0, 0])
            .count();
        assert!(ink > 20, "{ink}");
        assert_eq!(l.get_pixel(5, LABEL_PX + 5).0, [0, 128, 0]);
        assert_eq!(chars_in(40), 6);
        assert_eq!(labelled(&tile, "a\nb").height(), 20 + 2 * LABEL_PX);
        let s = sheet(&[vec![l.clone(), l.clone()], vec![l]], 4);
        assert_eq!(s.dimensions(), (2 * 44 + 4, 2 * (31 + 4) + 4));
        assert_eq!(s.get_pixel(4 + 44 + 5, 4 + LABEL_PX + 5).0, [0, 128, 0]);
        assert_eq!(s.get_pixel(4 + 44 + 5, 4 + 35 + LABEL_PX + 5).0, [255; 3]);
    }
}

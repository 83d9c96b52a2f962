//! Whether a capture's photos were taken before a plain backdrop (a sheet, a light box, a
//! rendering's empty background): their edges then show one colour nearly everywhere.
//!
//! Such a capture holds nothing worth a field beyond its subject, so its scene can be framed in
//! the small box every photo keeps in view, the backdrop learnt as a colour (see
//! [`super::framing::shared_view_half_extent`]). A capture whose edges show a room, a table or
//! a street keeps the larger box those need: a tight box there loses 2–3 dB (docs/measurements.md).

use super::scene::View;

/// Width of the ring along each photo's edges that is read, as a share of its shorter side.
pub const EDGE_SHARE: f32 = 0.03;
/// How far (largest channel difference, colours in `[0, 1]`) an edge pixel may stray from the
/// backdrop's colour and still count as backdrop: a lit sheet's shading and JPEG noise stay
/// within it; a wall, a floor or a table's grain do not.
pub const BACKDROP_TOLERANCE: f32 = 0.12;
/// Share of all edge pixels that must be backdrop: the subject may touch a few photos' edges.
pub const BACKDROP_SHARE: f32 = 0.9;

/// What the photos' edges show.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeColour {
    /// The edges' per-channel median colour, in `[0, 1]`.
    pub colour: [f32; 3],
    /// Share of the edge pixels within [`BACKDROP_TOLERANCE`] of it.
    pub share: f32,
}

impl EdgeColour {
    /// Whether the edges are a plain backdrop ([`BACKDROP_SHARE`] of them one colour).
    pub fn is_plain(&self) -> bool {
        self.share >= BACKDROP_SHARE
    }
}

/// The colour along the edges of every view's photo and how much of them it covers; `None`
/// without views.
pub fn edge_colour(views: &[View]) -> Option<EdgeColour> {
    let mut pixels: Vec<[f32; 3]> = Vec::new();
    for v in views {
        let img = &v.image;
        let (w, h) = (img.width, img.height);
        if w == 0 || h == 0 {
            continue;
        }
        let ring = ((EDGE_SHARE * w.min(h) as f32).round() as u32).max(1);
        for y in 0..h {
            let row_in_ring = y < ring || y + ring >= h;
            for x in 0..w {
                if row_in_ring || x < ring || x + ring >= w {
                    pixels.push(img.rgb(x, y));
                }
            }
        }
    }
    if pixels.is_empty() {
        return None;
    }
    let colour: [f32; 3] = std::array::from_fn(|c| {
        let mut ch: Vec<f32> = pixels.iter().map(|p| p[c]).collect();
        let mid = ch.len() / 2;
        *ch.select_nth_unstable_by(mid, f32::total_cmp).1
    });
    let near = pixels
        .iter()
        .filter(|p| (0..3).all(|c| (p[c] - colour[c]).abs() <= BACKDROP_TOLERANCE))
        .count();
    Some(EdgeColour {
        colour,
        share: near as f32 / pixels.len() as f32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::data::images::Image;

    /// A 40×30 view: `backdrop` everywhere but what `paint` colours.
    fn view(backdrop: [f32; 3], paint: impl Fn(u32, u32) -> Option<[f32; 3]>) -> View {
        let (w, h) = (40u32, 30u32);
        let rgb: Vec<f32> = (0..w * h)
            .flat_map(|i| paint(i % w, i / w).unwrap_or(backdrop))
            .collect();
        View {
            camera: Camera::look_at(
                w,
                h,
                30.0,
                [0.0, -4.0, 0.0].into(),
                [0.0; 3].into(),
                [0.0, 0.0, 1.0].into(),
            ),
            image: Image::from_f32(w, h, &rgb),
            mask: None,
            path: "view.png".into(),
            mask_path: None,
            depth_range: None,
        }
    }

    #[test]
    fn an_object_before_a_sheet_is_a_plain_backdrop_and_a_room_is_not() {
        let sheet = [0.92, 0.92, 0.9];
        // The subject in the middle, in one view reaching the bottom edge.
        let object = |x: u32, y: u32| {
            (10..30)
                .contains(&x)
                .then_some([0.8, 0.2, 0.1])
                .filter(|_| (8..22).contains(&y))
        };
        let touching = |x: u32, y: u32| {
            (10..30)
                .contains(&x)
                .then_some([0.1, 0.3, 0.8])
                .filter(|_| y >= 8)
        };
        let views = [
            view(sheet, object),
            view(sheet, object),
            view(sheet, touching),
        ];
        let e = edge_colour(&views).unwrap();
        assert!(e.is_plain(), "{e:?}");
        assert!(
            (0..3).all(|c| (e.colour[c] - sheet[c]).abs() < 0.01),
            "{e:?}"
        );

        // Walls with a floor: the lower third of every edge another colour.
        let floor = |_x: u32, y: u32| (y >= 20).then_some([0.35, 0.25, 0.15]);
        let room = [view(sheet, floor), view(sheet, floor)];
        assert!(!edge_colour(&room).unwrap().is_plain());

        // A textured wall: stripes of light and dark.
        let stripes = |x: u32, _y: u32| (x % 4 < 2).then_some([0.2, 0.2, 0.2]);
        assert!(!edge_colour(&[view(sheet, stripes)]).unwrap().is_plain());
        assert!(edge_colour(&[]).is_none());
    }

    #[test]
    fn shading_and_noise_on_the_sheet_stay_plain() {
        // A light falling off across the sheet by 0.15, with ±0.02 of noise.
        let shaded = |x: u32, y: u32| {
            let noise = (((x * 7 + y * 13) % 5) as f32 - 2.0) * 0.01;
            let v = 0.95 - 0.15 * x as f32 / 40.0 + noise;
            Some([v, v, v - 0.02])
        };
        let e = edge_colour(&[view([0.0; 3], shaded)]).unwrap();
        assert!(e.is_plain(), "{e:?}");
    }
}

//! How far an image's texture is from a painting's, position by position: the nearest-neighbour
//! feature distance. For each position of the image that lies on the object, 1 − the best
//! cosine similarity of its VGG feature to any position of the painting; averaged over the
//! object. It is ARF's NNFM loss as a measure.
//!
//! Unlike a Gram distance it does not average the painting's statistics over the whole canvas:
//! a pale wash on the object is not "close" to a painting because the painting has a pale sky
//! somewhere. At the shallow layers (relu1_2, relu2_2) it mostly sees colour, at the deep ones
//! (relu3_3, relu4_3) strokes and texture.

use burn::prelude::*;

/// Positions of the painting kept per layer: a regular subsample (the same for every image
/// scored) keeps the brute-force search at a few GFLOP per image.
pub const MAX_PAINTING_POSITIONS: usize = 8192;

/// Rows of the image processed at once (bounds the `[rows, painting positions]` similarity
/// block to 64 MB).
const CHUNK: usize = 2048;

/// Columns scaled to unit length (a zero column stays zero).
pub fn unit_columns(f: Tensor<2>) -> Tensor<2> {
    let norm = f.clone().square().sum_dim(0).sqrt().clamp_min(1e-8);
    f / norm
}

/// The features `[1, C, H, W]` at the positions where `keep` (one flag per position, row major)
/// is true, as columns `[C, N]`; `None` when no position is kept.
pub fn positions(features: Tensor<4>, keep: &[bool]) -> Option<Tensor<2>> {
    let [_, c, h, w] = features.dims();
    assert_eq!(keep.len(), h * w, "one flag per position");
    let idx: Vec<i64> = (0..h * w).filter(|&i| keep[i]).map(|i| i as i64).collect();
    if idx.is_empty() {
        return None;
    }
    let device = features.device();
    let n = idx.len();
    let idx = Tensor::<1, Int>::from_data(TensorData::new(idx, [n]), &device);
    Some(features.reshape([c, h * w]).select(1, idx))
}

/// Every `stride`-th position of the painting's features `[1, C, H, W]` in both directions, the
/// stride the smallest that keeps at most [`MAX_PAINTING_POSITIONS`], as columns `[C, M]`.
pub fn painting_positions(features: Tensor<4>) -> Tensor<2> {
    let [_, _, h, w] = features.dims();
    let mut stride = 1;
    while h.div_ceil(stride) * w.div_ceil(stride) > MAX_PAINTING_POSITIONS {
        stride += 1;
    }
    let keep: Vec<bool> = (0..h * w)
        .map(|i| (i / w).is_multiple_of(stride) && (i % w).is_multiple_of(stride))
        .collect();
    positions(features, &keep).expect("a painting has positions")
}

/// The mean over the columns of `image [C, N]` of 1 − the largest cosine similarity to any
/// column of `painting [C, M]`.
pub fn nn_distance(image: Tensor<2>, painting: Tensor<2>) -> f64 {
    let [_, n] = image.dims();
    let f = unit_columns(image);
    let s = unit_columns(painting);
    let mut total = 0.0f64;
    let mut start = 0;
    while start < n {
        let end = (start + CHUNK).min(n);
        let block = f
            .clone()
            .slice([0..f.dims()[0], start..end])
            .transpose()
            .matmul(s.clone());
        total += block.max_dim(1).sum().into_scalar::<f32>() as f64;
        start = end;
    }
    1.0 - total / n.max(1) as f64
}

/// The object mask of an image at a layer's resolution: a position of the `lw × lh` layer
/// covers a block of the `w × h` image, and counts as the object when at least half of its
/// pixels do.
pub fn mask_at_layer(mask: &[bool], w: usize, h: usize, lw: usize, lh: usize) -> Vec<bool> {
    assert_eq!(mask.len(), w * h, "one flag per pixel");
    let (sx, sy) = (w as f64 / lw as f64, h as f64 / lh as f64);
    (0..lw * lh)
        .map(|i| {
            let (lx, ly) = (i % lw, i / lw);
            let (x0, x1) = (
                (lx as f64 * sx) as usize,
                (((lx + 1) as f64 * sx) as usize).min(w),
            );
            let (y0, y1) = (
                (ly as f64 * sy) as usize,
                (((ly + 1) as f64 * sy) as usize).min(h),
            );
            let (mut on, mut all) = (0, 0);
            for y in y0..y1.max(y0 + 1).min(h) {
                for x in x0..x1.max(x0 + 1).min(w) {
                    all += 1;
                    on += mask[y * w + x] as usize;
                }
            }
            all > 0 && 2 * on >= all
        })
        .collect()
}

/// The share of the way from `before` to `reference` that `after` went: 0 where it stayed, 1
/// where it arrived (beyond 1 past it). `None` when the reference is no nearer than `before`
/// (nothing to transfer).
pub fn transfer_ratio(before: f64, after: f64, reference: f64) -> Option<f64> {
    let way = before - reference;
    (way > 1e-9).then(|| (before - after) / way)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t2(rows: &[&[f32]], device: &Device) -> Tensor<2> {
        let (r, c) = (rows.len(), rows[0].len());
        let data: Vec<f32> = rows.iter().flat_map(|row| row.iter().copied()).collect();
        Tensor::from_data(TensorData::new(data, [r, c]), device)
    }

    #[test]
    fn the_distance_is_the_mean_of_one_minus_the_best_cosine_computed_by_hand() {
        let d = Device::flex();
        // Image columns (C = 2): (1, 0), (1, 1), (0, 2). Painting columns: (1, 0), (0, 1).
        let image = t2(&[&[1.0, 1.0, 0.0], &[0.0, 1.0, 2.0]], &d);
        let painting = t2(&[&[1.0, 0.0], &[0.0, 1.0]], &d);
        // Best cosines: 1, 1/√2, 1.
        let expected = ((1.0 - 1.0) + (1.0 - 0.5f64.sqrt()) + (1.0 - 1.0)) / 3.0;
        let got = nn_distance(image, painting);
        assert!((got - expected).abs() < 1e-6, "{got} vs {expected}");
    }

    #[test]
    fn masked_positions_and_layer_masks_pick_the_object() {
        let d = Device::flex();
        // A 1×2×2×2 feature map; keep positions 0 and 3.
        let f = Tensor::<1>::from_floats([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0], &d)
            .reshape([1, 2, 2, 2]);
        let p = positions(f, &[true, false, false, true]).unwrap();
        assert_eq!(
            p.into_data().try_to_vec::<f32>().unwrap(),
            vec![1.0, 4.0, 5.0, 8.0]
        );
        // A 4×4 mask whose left half is the object, at 2×2: the left column.
        let mask: Vec<bool> = (0..16).map(|i| i % 4 < 2).collect();
        assert_eq!(
            mask_at_layer(&mask, 4, 4, 2, 2),
            vec![true, false, true, false]
        );
        // A block half covered counts.
        let mask: Vec<bool> = (0..16).map(|i| i % 4 == 0).collect();
        assert_eq!(
            mask_at_layer(&mask, 4, 4, 2, 2),
            vec![true, false, true, false]
        );
    }

    #[test]
    fn the_transfer_ratio_is_zero_at_the_floor_and_one_at_the_reference() {
        assert_eq!(transfer_ratio(0.8, 0.8, 0.4), Some(0.0));
        assert_eq!(transfer_ratio(0.8, 0.4, 0.4), Some(1.0));
        assert!((transfer_ratio(0.8, 0.6, 0.4).unwrap() - 0.5).abs() < 1e-12);
        assert_eq!(transfer_ratio(0.4, 0.3, 0.4), None);
    }

    #[test]
    fn painting_positions_are_capped_by_a_regular_stride() {
        let d = Device::flex();
        let f = Tensor::<4>::ones([1, 3, 200, 100], &d);
        let p = painting_positions(f);
        let [c, m] = p.dims();
        assert_eq!(c, 3);
        assert!(
            m <= MAX_PAINTING_POSITIONS && m > MAX_PAINTING_POSITIONS / 4,
            "{m}"
        );
    }
}

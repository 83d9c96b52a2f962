//! Loss terms: Gram-matrix style loss, VGG content loss, pixel MSE, and the image metrics
//! (PSNR, SSIM).
//!
//! Style: Σ over relu1_2, relu2_2, relu3_3, relu4_3 of mean((G(x) − G(s))²) with
//! G = F Fᵀ / (C·H·W). Content: mean((relu2_2(x) − relu2_2(c))²).

pub mod color_transfer;
pub mod gram;
pub mod guided_match;
pub mod perceptual;
pub mod pixel;
pub mod saturation;
pub mod ssim;
pub mod style;
pub mod weights;

pub use color_transfer::ColorTransfer;
pub use gram::{StyleTarget, gram, style_distance, style_loss};
pub use perceptual::{
    ContentTarget, PerceptualLoss, content_distance, content_loss, one_hot_codes, patch_images,
    photo_patch,
};
pub use pixel::{mse, psnr};
pub use ssim::ssim;
pub use style::{MatchGuide, PhotoGuide, StyleLoss, StyleTargets};
pub use weights::LossWeights;

//! Scale factors and σ² per pyramid level (ORB-SLAM2 `mvScaleFactors`, `mvLevelSigma2`), the
//! pyramid the keypoint octaves of an extractor refer to.

/// Scale factors and σ² per pyramid level (ORB-SLAM2 `mvScaleFactors`, `mvLevelSigma2`).
#[derive(Clone, Debug, PartialEq)]
pub struct ScalePyramid {
    /// Number of levels.
    pub levels: usize,
    /// Scale factor between levels.
    pub scale_factor: f32,
    /// scale^level.
    pub scale: Vec<f32>,
    /// 1 / scale^level.
    pub inv_scale: Vec<f32>,
    /// scale^(2·level).
    pub sigma2: Vec<f32>,
    /// 1 / scale^(2·level).
    pub inv_sigma2: Vec<f32>,
}

impl ScalePyramid {
    /// Pyramid of `levels` levels with factor `scale_factor`.
    pub fn new(levels: usize, scale_factor: f32) -> Self {
        let levels = levels.max(1);
        let scale: Vec<f32> = (0..levels).map(|l| scale_factor.powi(l as i32)).collect();
        let sigma2: Vec<f32> = scale.iter().map(|s| s * s).collect();
        Self {
            levels,
            scale_factor,
            inv_scale: scale.iter().map(|s| 1.0 / s).collect(),
            inv_sigma2: sigma2.iter().map(|s| 1.0 / s).collect(),
            scale,
            sigma2,
        }
    }

    /// Scale of `level` (1 when out of range).
    pub fn scale_of(&self, level: usize) -> f32 {
        self.scale.get(level).copied().unwrap_or(1.0)
    }

    /// σ² of `level`.
    pub fn sigma2_of(&self, level: usize) -> f32 {
        self.sigma2.get(level).copied().unwrap_or(1.0)
    }

    /// 1/σ² of `level`.
    pub fn inv_sigma2_of(&self, level: usize) -> f32 {
        self.inv_sigma2.get(level).copied().unwrap_or(1.0)
    }
}

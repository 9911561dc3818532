//! Frames: a value holding one RGB-D image's features (spec §6.1, §2.2/§7.18): keypoints at
//! their image position and undistorted, descriptors, depth per keypoint sampled at the
//! distorted pixel, the virtual right coordinate uR = u − bf/d, the per-keypoint DynaPix
//! weight (sampled once here, at the image position), the 64×48 feature grid over the
//! undistorted image bounds, and the matches to map points.

use dynapix_geometry::Se3;
use image::{ImageBuffer, Luma};
use nalgebra::Vector3;

use crate::camera::{ImageBounds, RgbdCamera};
use crate::features::{Descriptor, KeyPoint};
use crate::ids::{KeyFrameId, MapPointId};
use crate::pose::transform;
use crate::vocab::Vocabulary;

/// Depth image in metres (0 = no measurement).
pub type DepthImage = ImageBuffer<Luma<f32>, Vec<f32>>;
/// Per-pixel DynaPix weight image w = 1 − P in [0, 1] (the image inside
/// [`dynapix_io::StaticWeights`]).
pub type WeightImage = dynapix_io::WeightImage;

/// Bag-of-words vector: `(word, weight)` sorted by word.
pub type BowWords = Vec<(u32, f64)>;
/// Feature vector: `(vocabulary node, keypoint indices)` sorted by node.
pub type FeatureGroups = Vec<(u32, Vec<u32>)>;

/// BoW vector `(word, weight)` and feature vector `node → keypoint indices` grouped at tree
/// depth `group_depth` (2 ≈ ORB-SLAM2's `levels_up = 4` on its 6-level vocabulary).
pub fn bow_vectors(
    vocab: &Vocabulary,
    descs: &[Descriptor],
    group_depth: usize,
) -> (BowWords, FeatureGroups) {
    let levels_up = vocab.levels().saturating_sub(group_depth);
    let (bow, feat) = vocab.transform_with_levels_up(descs, levels_up);
    (
        bow.as_slice().to_vec(),
        feat.iter()
            .map(|(n, v)| (*n, v.iter().map(|&i| i as u32).collect()))
            .collect(),
    )
}

/// Grid columns (ORB-SLAM2 `FRAME_GRID_COLS`).
pub const GRID_COLS: usize = 64;
/// Grid rows (ORB-SLAM2 `FRAME_GRID_ROWS`).
pub const GRID_ROWS: usize = 48;

/// Keypoint indices bucketed in a 64×48 grid over the undistorted image bounds.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureGrid {
    /// Image bounds the grid spans.
    pub bounds: ImageBounds,
    inv_w: f32,
    inv_h: f32,
    cells: Vec<Vec<u32>>,
    levels: Vec<u8>,
    xs: Vec<f32>,
    ys: Vec<f32>,
}

impl FeatureGrid {
    /// A grid with no keypoints.
    pub fn empty() -> Self {
        Self {
            bounds: ImageBounds {
                min_x: 0.0,
                max_x: 1.0,
                min_y: 0.0,
                max_y: 1.0,
            },
            inv_w: GRID_COLS as f32,
            inv_h: GRID_ROWS as f32,
            cells: vec![Vec::new(); GRID_COLS * GRID_ROWS],
            levels: Vec::new(),
            xs: Vec::new(),
            ys: Vec::new(),
        }
    }

    /// Buckets `keys_un` within `bounds`; keypoints outside are left out.
    pub fn new(bounds: ImageBounds, keys_un: &[KeyPoint]) -> Self {
        let inv_w = GRID_COLS as f32 / (bounds.max_x - bounds.min_x).max(1e-6);
        let inv_h = GRID_ROWS as f32 / (bounds.max_y - bounds.min_y).max(1e-6);
        let mut cells = vec![Vec::new(); GRID_COLS * GRID_ROWS];
        for (i, k) in keys_un.iter().enumerate() {
            let gx = ((k.x - bounds.min_x) * inv_w).round();
            let gy = ((k.y - bounds.min_y) * inv_h).round();
            if gx < 0.0 || gy < 0.0 || gx >= GRID_COLS as f32 || gy >= GRID_ROWS as f32 {
                continue;
            }
            if let Some(c) = cells.get_mut(gy as usize * GRID_COLS + gx as usize) {
                c.push(i as u32);
            }
        }
        Self {
            bounds,
            inv_w,
            inv_h,
            cells,
            levels: keys_un.iter().map(|k| k.octave).collect(),
            xs: keys_un.iter().map(|k| k.x).collect(),
            ys: keys_un.iter().map(|k| k.y).collect(),
        }
    }

    /// Indices of keypoints within a square of half-size `r` around (x, y), with octave in
    /// `[min_level, max_level]` (`min_level ≤ 0` / `max_level < 0` disable the bounds), in
    /// grid order (ORB-SLAM2 `GetFeaturesInArea`).
    pub fn features_in_area(
        &self,
        x: f32,
        y: f32,
        r: f32,
        min_level: i32,
        max_level: i32,
    ) -> Vec<usize> {
        let mut out = Vec::new();
        let b = &self.bounds;
        let min_cx = ((x - b.min_x - r) * self.inv_w).floor().max(0.0);
        if !min_cx.is_finite() || min_cx >= GRID_COLS as f32 {
            return out;
        }
        let max_cx = ((x - b.min_x + r) * self.inv_w)
            .ceil()
            .min(GRID_COLS as f32 - 1.0);
        if max_cx < 0.0 {
            return out;
        }
        let min_cy = ((y - b.min_y - r) * self.inv_h).floor().max(0.0);
        if !min_cy.is_finite() || min_cy >= GRID_ROWS as f32 {
            return out;
        }
        let max_cy = ((y - b.min_y + r) * self.inv_h)
            .ceil()
            .min(GRID_ROWS as f32 - 1.0);
        if max_cy < 0.0 {
            return out;
        }
        let check = min_level > 0 || max_level >= 0;
        for cy in min_cy as usize..=max_cy as usize {
            for cx in min_cx as usize..=max_cx as usize {
                let Some(cell) = self.cells.get(cy * GRID_COLS + cx) else {
                    continue;
                };
                for &i in cell {
                    let i = i as usize;
                    let (Some(&lv), Some(&kx), Some(&ky)) =
                        (self.levels.get(i), self.xs.get(i), self.ys.get(i))
                    else {
                        continue;
                    };
                    if check {
                        if (lv as i32) < min_level {
                            continue;
                        }
                        if max_level >= 0 && lv as i32 > max_level {
                            continue;
                        }
                    }
                    if (kx - x).abs() < r && (ky - y).abs() < r {
                        out.push(i);
                    }
                }
            }
        }
        out
    }
}

/// One RGB-D frame's features and tracking state (a value; the tracker owns the current and
/// the last frame).
#[derive(Clone, Debug)]
pub struct Frame {
    /// Frame number in the input sequence.
    pub id: u64,
    /// Timestamp in seconds.
    pub timestamp: f64,
    /// Keypoints at their image (distorted) position.
    pub keys: Vec<KeyPoint>,
    /// Undistorted keypoints.
    pub keys_un: Vec<KeyPoint>,
    /// Descriptors.
    pub descriptors: Vec<Descriptor>,
    /// Depth per keypoint (metres), −1 when missing.
    pub depth: Vec<f32>,
    /// Virtual right coordinate uR = u − bf/d, −1 when missing.
    pub u_right: Vec<f32>,
    /// DynaPix weight w = 1 − P per keypoint (1.0 for ORB-SLAM2).
    pub weights: Vec<f32>,
    /// Keypoint lies on a semantically dynamic class (DynaPix+ masks; gates map-point birth).
    pub dynamic_class: Vec<bool>,
    /// Map point matched to each keypoint.
    pub map_points: Vec<Option<MapPointId>>,
    /// Outlier flag of each match after pose optimisation.
    pub outlier: Vec<bool>,
    /// Feature grid.
    pub grid: FeatureGrid,
    /// Bag-of-words words `(word, weight)` sorted by word (empty without a vocabulary).
    pub bow: Vec<(u32, f64)>,
    /// Feature vector: node → keypoint indices, sorted by node (empty without a vocabulary).
    pub feat: Vec<(u32, Vec<u32>)>,
    /// Pose `T_cw` once estimated.
    pub pose: Option<Se3>,
    /// Reference keyframe.
    pub reference: Option<KeyFrameId>,
}

impl Frame {
    /// Builds a frame from extracted features. Keypoints whose weight is exactly 0 are
    /// removed (spec §2.2); depth is sampled at the distorted pixel; invalid, non-finite or
    /// absurd depths count as missing.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        id: u64,
        timestamp: f64,
        keys: Vec<KeyPoint>,
        descriptors: Vec<Descriptor>,
        depth: &DepthImage,
        weight_map: Option<&WeightImage>,
        cam: &RgbdCamera,
        bounds: ImageBounds,
    ) -> Self {
        let n0 = keys.len().min(descriptors.len());
        let sample = |img: &ImageBuffer<Luma<f32>, Vec<f32>>, k: &KeyPoint| -> Option<f32> {
            if !(k.x >= 0.0 && k.y >= 0.0) {
                return None;
            }
            let (x, y) = (k.x as u32, k.y as u32);
            if x >= img.width() || y >= img.height() {
                return None;
            }
            Some(img.get_pixel(x, y).0[0])
        };
        let mut kk = Vec::with_capacity(n0);
        let mut dd = Vec::with_capacity(n0);
        let mut ww = Vec::with_capacity(n0);
        for (k, d) in keys.into_iter().zip(descriptors).take(n0) {
            let w = match weight_map {
                Some(m) => sample(m, &k).unwrap_or(1.0),
                None => 1.0,
            };
            let w = if w.is_finite() {
                w.clamp(0.0, 1.0)
            } else {
                1.0
            };
            if w == 0.0 {
                continue;
            }
            kk.push(k);
            dd.push(d);
            ww.push(w);
        }
        let n = kk.len();
        let mut keys_un = kk.clone();
        for k in keys_un.iter_mut() {
            let (u, v) = cam.undistort(k.x as f64, k.y as f64);
            k.x = u as f32;
            k.y = v as f32;
        }
        let mut depth_v = vec![-1.0f32; n];
        let mut ur = vec![-1.0f32; n];
        for i in 0..n {
            let d = sample(depth, &kk[i]).unwrap_or(0.0);
            if d.is_finite() && d > 0.0 && (d as f64) <= cam.max_depth {
                depth_v[i] = d;
                ur[i] = keys_un[i].x - (cam.bf / d as f64) as f32;
            }
        }
        let grid = FeatureGrid::new(bounds, &keys_un);
        Self {
            id,
            timestamp,
            keys: kk,
            keys_un,
            descriptors: dd,
            depth: depth_v,
            u_right: ur,
            weights: ww,
            dynamic_class: vec![false; n],
            map_points: vec![None; n],
            outlier: vec![false; n],
            grid,
            bow: Vec::new(),
            feat: Vec::new(),
            pose: None,
            reference: None,
        }
    }

    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.keys_un.len()
    }

    /// True when the frame has no keypoints.
    pub fn is_empty(&self) -> bool {
        self.keys_un.is_empty()
    }

    /// Computes the bag-of-words and feature vectors once (no-op when already done).
    pub fn compute_bow(&mut self, vocab: &Vocabulary, group_depth: usize) {
        if self.bow.is_empty() && !self.descriptors.is_empty() {
            (self.bow, self.feat) = bow_vectors(vocab, &self.descriptors, group_depth);
        }
    }

    /// Camera centre in world coordinates (None before the pose is set).
    pub fn center(&self) -> Option<Vector3<f64>> {
        self.pose.map(|p| p.inverse().translation.vector)
    }

    /// Back-projects keypoint `i` with its depth into world coordinates.
    pub fn unproject(&self, i: usize, cam: &RgbdCamera) -> Option<Vector3<f64>> {
        let z = *self.depth.get(i)? as f64;
        let pose = self.pose?;
        if z <= 0.0 {
            return None;
        }
        let kp = self.keys_un.get(i)?;
        let xc = Vector3::new(
            (kp.x as f64 - cam.pinhole.cx) * z / cam.pinhole.fx,
            (kp.y as f64 - cam.pinhole.cy) * z / cam.pinhole.fy,
            z,
        );
        Some(transform(&pose.inverse(), &xc))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynapix_geometry::PinholeCamera;

    fn fr1() -> RgbdCamera {
        let mut p = PinholeCamera::new(640, 480, 517.306408, 516.469215, 318.643040, 255.313989);
        p.dist = [0.262383, -0.953104, -0.005358, 0.002628, 1.163314];
        RgbdCamera::new(p, 40.0, 40.0, 30.0)
    }

    fn distort(c: &PinholeCamera, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = c.dist;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        (xd * c.fx + c.cx, yd * c.fy + c.cy)
    }

    #[test]
    fn undistortion_inverts_the_distortion_model() {
        let cam = fr1();
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.5, 0.4), (0.55, 0.45)] {
            let (u, v) = distort(&cam.pinhole, x, y);
            let (uu, vv) = cam.undistort(u, v);
            let ex = (uu - cam.pinhole.cx) / cam.pinhole.fx - x;
            let ey = (vv - cam.pinhole.cy) / cam.pinhole.fy - y;
            assert!(ex.abs() < 1e-6 && ey.abs() < 1e-6, "{x} {y}: {ex} {ey}");
        }
        let b = cam.image_bounds();
        // Positive k1 pulls the corners inwards: the undistorted bounds lie inside the image.
        assert!(
            b.min_x > 0.0 && b.max_x < 640.0 && b.max_x - b.min_x > 550.0,
            "{b:?}"
        );
        assert!(
            b.min_y > 0.0 && b.max_y < 480.0 && b.max_y - b.min_y > 400.0,
            "{b:?}"
        );
    }

    #[test]
    fn depth_and_virtual_right_and_grid() {
        let cam = RgbdCamera::new(PinholeCamera::tum_fr3(), 40.0, 40.0, 30.0);
        let mut depth = DepthImage::new(640, 480);
        depth.put_pixel(100, 50, Luma([2.0]));
        depth.put_pixel(200, 60, Luma([1000.0]));
        let kp = |x: f32, y: f32| KeyPoint {
            x,
            y,
            angle: 0.0,
            response: 1.0,
            octave: 0,
            size: 31.0,
        };
        let keys = vec![kp(100.7, 50.2), kp(200.0, 60.0), kp(300.0, 300.0)];
        let mut w = WeightImage::from_pixel(640, 480, Luma([1.0]));
        w.put_pixel(300, 300, Luma([0.0]));
        let f = Frame::new(
            0,
            0.0,
            keys,
            vec![[0u8; 32]; 3],
            &depth,
            Some(&w),
            &cam,
            cam.image_bounds(),
        );
        assert_eq!(f.len(), 2, "weight-0 keypoint removed");
        assert_eq!(f.depth[0], 2.0);
        assert!((f.u_right[0] - (100.7 - 20.0)).abs() < 1e-4);
        assert_eq!(f.depth[1], -1.0, "absurd depth is missing");
        let near = f.grid.features_in_area(101.0, 50.0, 3.0, -1, -1);
        assert_eq!(near, vec![0]);
        assert!(f.grid.features_in_area(101.0, 50.0, 3.0, 1, -1).is_empty());
    }
}

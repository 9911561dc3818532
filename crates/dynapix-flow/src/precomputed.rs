//! A [`FlowProvider`] that reads flows computed elsewhere (e.g. by a network such as
//! FlowFormer, which the reference implementation runs on a GPU) from Middlebury `.flo`
//! files. The file of a request is found from the frame names ([`FramePair`]) by a naming
//! rule: a closure, or a folder plus a template with `{a}` and `{b}` placeholders.

use crate::flo::read_flo;
use crate::{FlowError, FlowField, FlowProvider, FramePair};
use image::GrayImage;
use std::path::{Path, PathBuf};

type Resolver = dyn Fn(&str, &str) -> PathBuf + Send + Sync;

/// Reads precomputed `.flo` flows; see the module documentation.
pub struct PrecomputedFlow {
    resolver: Box<Resolver>,
}

impl std::fmt::Debug for PrecomputedFlow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PrecomputedFlow").finish_non_exhaustive()
    }
}

impl PrecomputedFlow {
    /// A provider whose file for frames (a, b) is `resolve(a, b)`.
    pub fn from_fn(resolve: impl Fn(&str, &str) -> PathBuf + Send + Sync + 'static) -> Self {
        Self {
            resolver: Box::new(resolve),
        }
    }

    /// A provider reading `dir/<template>` with `{a}` and `{b}` replaced by the frame names,
    /// e.g. `PrecomputedFlow::in_dir("flows", "{a}_{b}.flo")`.
    pub fn in_dir(dir: impl AsRef<Path>, template: &str) -> Self {
        let dir = dir.as_ref().to_path_buf();
        let template = template.to_string();
        Self::from_fn(move |a, b| dir.join(template.replace("{a}", a).replace("{b}", b)))
    }

    /// The file that holds the flow between frames `a` and `b`.
    pub fn path_for(&self, a: &str, b: &str) -> PathBuf {
        (self.resolver)(a, b)
    }

    /// Reads the flow of frames (a, b), checking its size against `width × height`.
    pub fn load(&self, a: &str, b: &str, width: u32, height: u32) -> Result<FlowField, FlowError> {
        let path = self.path_for(a, b);
        let flow = read_flo(&path)?;
        if (flow.width, flow.height) != (width, height) {
            return Err(FlowError::BadFile {
                path,
                reason: format!(
                    "flow is {} x {} but the images are {width} x {height}",
                    flow.width, flow.height
                ),
            });
        }
        Ok(flow)
    }
}

impl FlowProvider for PrecomputedFlow {
    /// Precomputed flows are looked up by frame name: without names there is no file to read.
    fn flow(&self, _a: &GrayImage, _b: &GrayImage) -> Result<FlowField, FlowError> {
        Err(FlowError::Other(
            "precomputed flows are found by frame name: call flow_named with the frame names"
                .to_string(),
        ))
    }

    fn flow_named(
        &self,
        a: &GrayImage,
        b: &GrayImage,
        names: FramePair<'_>,
    ) -> Result<FlowField, FlowError> {
        if a.dimensions() != b.dimensions() {
            return Err(FlowError::SizeMismatch {
                a: a.dimensions(),
                b: b.dimensions(),
            });
        }
        self.load(names.a, names.b, a.width(), a.height())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flo::write_flo;

    #[test]
    fn reads_named_flow_and_reports_bad_files() {
        let dir = tempfile::tempdir().unwrap();
        let f = FlowField::constant(4, 3, [1.5, -0.25]);
        write_flo(dir.path().join("10_11.flo"), &f).unwrap();
        let prov = PrecomputedFlow::in_dir(dir.path(), "{a}_{b}.flo");
        let img = GrayImage::new(4, 3);
        let names = FramePair { a: "10", b: "11" };
        assert_eq!(prov.flow_named(&img, &img, names).unwrap(), f);

        let e = prov
            .flow_named(&img, &img, FramePair { a: "10", b: "12" })
            .unwrap_err()
            .to_string();
        assert!(e.contains("10_12.flo"), "{e}");

        let big = GrayImage::new(5, 3);
        let e = prov.flow_named(&big, &big, names).unwrap_err().to_string();
        assert!(e.contains("10_11.flo") && e.contains("5 x 3"), "{e}");

        assert!(prov.flow(&img, &img).is_err());
    }

    #[test]
    fn closure_naming_rule() {
        let prov = PrecomputedFlow::from_fn(|a, b| PathBuf::from(format!("/x/{b}-{a}.flo")));
        assert_eq!(prov.path_for("1", "2"), PathBuf::from("/x/2-1.flo"));
    }
}

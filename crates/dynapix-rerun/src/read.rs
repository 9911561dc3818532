//! Reading a saved recording back: which entities it holds and how many rows each has, per
//! timeline. Used by the tests and by checks of a recording (`rerun rrd stats` needs the
//! Python package; this needs nothing).

use std::collections::BTreeMap;
use std::path::Path;

use rerun::external::re_log_encoding::DecoderApp;
use rerun::log::{Chunk, LogMsg};

use crate::{Error, Result};

/// What a recording holds.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Contents {
    /// Rows logged at each entity path of the recording (not of its layout), all timelines
    /// and static data together.
    pub rows: BTreeMap<String, usize>,
    /// Rows logged on each timeline.
    pub timelines: BTreeMap<String, usize>,
    /// Layouts (blueprints) activated in the file.
    pub layouts: usize,
}

impl Contents {
    /// Rows at `path` (0 when absent).
    pub fn rows(&self, path: &str) -> usize {
        self.rows.get(path).copied().unwrap_or(0)
    }
}

/// Decodes the `.rrd` file `path`.
pub fn read_rrd(path: &Path) -> Result<Contents> {
    let err = |reason: String| Error::Read {
        path: path.to_path_buf(),
        reason,
    };
    let file = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
    let mut out = Contents::default();
    for msg in DecoderApp::decode_lazy(std::io::BufReader::new(file)) {
        let msg = msg.map_err(|e| err(e.to_string()))?;
        match &msg {
            LogMsg::ArrowMsg(store, arrow) => {
                if store.is_blueprint() {
                    continue;
                }
                let chunk = Chunk::from_arrow_msg(arrow).map_err(|e| err(e.to_string()))?;
                let path = chunk.entity_path().to_string();
                let path = path.strip_prefix('/').unwrap_or(&path).to_string();
                *out.rows.entry(path).or_default() += chunk.num_rows();
                for name in chunk.timelines().keys() {
                    *out.timelines.entry(name.to_string()).or_default() += chunk.num_rows();
                }
            }
            LogMsg::BlueprintActivationCommand(_) => out.layouts += 1,
            _ => {}
        }
    }
    Ok(out)
}

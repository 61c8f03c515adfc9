//! `map.sumo`: a real road network, read from a SUMO `.net.xml` next to the
//! spec (or, in a dataset, from its `networks/` folder) and built once into
//! the map every scenario of the section drives.

use super::*;
use crate::map::sumo::SumoNetwork;
use crate::map::CityMap;
use sha2::{Digest, Sha256};
use std::path::PathBuf;
use std::sync::Arc;

/// The network a `map.sumo` section names, once read: its map and the
/// bounds of everything drawn. Not part of the spec's JSON; two sections
/// naming the same file compare equal whether read or not.
#[derive(Clone, Default)]
pub struct LoadedNetwork(pub Option<Arc<ImportedNetwork>>);

/// A read and built SUMO network.
#[derive(Debug)]
pub struct ImportedNetwork {
    pub map: Arc<CityMap>,
    /// Lower and upper corners of the lanes and junction outlines, metres.
    pub bounds: (glam::DVec2, glam::DVec2),
    /// The file's bytes, as the dataset keeps them.
    pub bytes: Vec<u8>,
    /// The file it was read from.
    pub path: PathBuf,
}

impl PartialEq for LoadedNetwork {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl fmt::Debug for LoadedNetwork {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.0 {
            Some(n) => write!(f, "LoadedNetwork({})", n.path.display()),
            None => f.write_str("LoadedNetwork(not read)"),
        }
    }
}

/// The folder of a dataset that keeps the networks its spec names.
pub const NETWORKS_FOLDER: &str = "networks";

/// The file name a network keeps in a dataset's `networks/` folder.
pub fn network_file_name(sumo: &str) -> &str {
    Path::new(sumo).file_name().and_then(|n| n.to_str()).unwrap_or(sumo)
}

/// The bytes of the SUMO network file at `path`; an error naming it when it
/// cannot be read or is not a regular file (a pipe or a device would be
/// read without end).
pub fn read_network_file(path: &Path) -> Result<Vec<u8>, String> {
    let cannot = |why: String| format!("cannot read SUMO network {}: {why}", path.display());
    let metadata = std::fs::metadata(path).map_err(|e| cannot(e.to_string()))?;
    if !metadata.is_file() {
        return Err(cannot("not a regular file; give a .net.xml file".into()));
    }
    // (Read whole and parsed in memory: a file near the machine's memory
    // was read until the kernel killed the command.)
    crate::input::read_regular(path, MAX_NETWORK_BYTES).map_err(|e| {
        cannot(match e.kind() {
            std::io::ErrorKind::InvalidData => {
                format!("{e}; cut the area with netconvert (--keep-edges.in-boundary)")
            }
            _ => e.to_string(),
        })
    })
}

/// Largest `.net.xml` read, bytes: read whole and parsed in memory (several
/// times its size); a city district of a few thousand junctions, as the
/// maps here are drawn, is tens of MB, `tests/data/sumo/berlin-small.net.xml` 0.2 MB.
pub const MAX_NETWORK_BYTES: u64 = 1 << 30;

impl ImportedNetwork {
    /// Reads and builds the network at `path` with lane changes
    /// `lane_change_m` long; errors name `field`, the file and what is wrong.
    pub fn read(path: &Path, lane_change_m: f64, field: &str) -> Result<ImportedNetwork, SpecError> {
        let bytes = read_network_file(path).map_err(|e| SpecError::new(field, e))?;
        let text = std::str::from_utf8(&bytes)
            .map_err(|_| SpecError::new(field, format!("{}: not UTF-8 text, so not a .net.xml", path.display())))?;
        let net = SumoNetwork::from_xml(text).map_err(|e| SpecError::new(field, format!("{}: {e}", path.display())))?;
        let (map, _) = CityMap::from_sumo(&net, lane_change_m)
            .map_err(|e| SpecError::new(field, format!("{}: cannot be driven: {e}", path.display())))?;
        Ok(ImportedNetwork { map: Arc::new(map), bounds: net.bounds(), bytes, path: path.to_path_buf() })
    }
}

impl DatasetSpec {
    /// Every map section of the spec, with its field path: `map`, then the
    /// held-out splits' own.
    fn map_sections_mut(&mut self) -> Vec<(String, &mut MapSpec)> {
        let mut out = vec![("map".to_string(), &mut self.map)];
        for (name, held) in [("val", self.held_out.val.as_mut()), ("test", self.held_out.test.as_mut())] {
            if let Some(map) = held.and_then(|h| h.map.as_mut()) {
                out.push((format!("held_out.{name}.map"), map));
            }
        }
        out
    }

    /// Reads the SUMO networks the spec's map sections name, each from the
    /// path `locate` gives for its `sumo` value.
    pub fn read_networks(&mut self, locate: impl Fn(&str) -> PathBuf) -> Result<(), SpecError> {
        let mut read: Vec<(String, Arc<ImportedNetwork>)> = Vec::new();
        for (field, map) in self.map_sections_mut() {
            let Some(sumo) = map.sumo.clone() else { continue };
            let field = format!("{field}.sumo");
            let network = Arc::new(ImportedNetwork::read(&locate(&sumo), map.lane_change_m, &field)?);
            // A dataset keeps its networks by file name: one name, one network.
            let name = network_file_name(&sumo).to_string();
            if let Some((_, other)) = read.iter().find(|(n, o)| *n == name && o.bytes != network.bytes) {
                return Err(SpecError::new(
                    field,
                    format!(
                        "{} and {} are different networks of one file name, {name}: a dataset keeps its networks by name, so rename one",
                        other.path.display(),
                        network.path.display()
                    ),
                ));
            }
            // The spec as run pins the file's bytes.
            let sha: String = Sha256::digest(&network.bytes).iter().map(|b| format!("{b:02x}")).collect();
            if let Some(pinned) = map.sumo_sha256.as_ref().filter(|p| **p != sha) {
                return Err(SpecError::new(
                    format!("{field}_sha256"),
                    format!(
                        "{} has SHA-256 {sha}, not {pinned}: the network changed since the spec (or the dataset) was made on it",
                        network.path.display()
                    ),
                ));
            }
            map.sumo_sha256 = Some(sha);
            read.push((name, network.clone()));
            map.network = LoadedNetwork(Some(network));
        }
        Ok(())
    }

    /// Reads the networks of a spec file: a relative `sumo` path is taken
    /// from the spec file's folder.
    pub fn read_networks_beside(&mut self, spec_path: &Path) -> Result<(), SpecError> {
        let folder = spec_path.parent().map(Path::to_path_buf).unwrap_or_default();
        self.read_networks(|sumo| folder.join(sumo))
    }

    /// Reads the networks of a dataset's spec from its `networks/` folder.
    pub fn read_networks_in_dataset(&mut self, root: &Path) -> Result<(), SpecError> {
        let folder = root.join(NETWORKS_FOLDER);
        self.read_networks(|sumo| folder.join(network_file_name(sumo)))
    }

    /// Where the dataset in `root` keeps a copy of each network the spec
    /// names (read or not).
    pub fn network_copies(&mut self, root: &Path) -> Vec<PathBuf> {
        let folder = root.join(NETWORKS_FOLDER);
        self.map_sections_mut()
            .into_iter()
            .filter_map(|(_, map)| Some(folder.join(network_file_name(map.sumo.as_deref()?))))
            .collect()
    }

    /// The networks read, by the file name a dataset keeps them under.
    pub fn networks(&self) -> Vec<(String, Arc<ImportedNetwork>)> {
        let held = [self.held_out.val.as_ref(), self.held_out.test.as_ref()];
        std::iter::once(&self.map)
            .chain(held.into_iter().flatten().filter_map(|h| h.map.as_ref()))
            .filter_map(|m| Some((network_file_name(m.sumo.as_deref()?).to_string(), m.network.0.clone()?)))
            .collect()
    }
}

//! A written dataset opened for reading: its manifest, the spec it was made
//! from, and where each of its scenarios lives. Used by every command that
//! reads datasets (stats, heatmap, exports).

use crate::map::CityMap;
use crate::orchestrate::plan::{Expansion, ScenarioKey};
use crate::output::manifest::ManifestRecord;
use crate::output::scenario_dir;
use crate::spec::{DatasetSpec, Split};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A dataset folder and what its manifest says it holds.
pub struct Dataset {
    pub dir: PathBuf,
    pub record: ManifestRecord,
    pub expansion: Expansion,
    pub keys: Vec<ScenarioKey>,
}

impl Dataset {
    /// Opens the dataset in `dir`; errors name the folder and what is wrong.
    pub fn open(dir: &Path) -> Result<Dataset, String> {
        let manifest = dir.join("manifest.json");
        let record = ManifestRecord::read(&manifest)?
            .ok_or_else(|| format!("no manifest.json in {}: not a causalcity dataset", dir.display()))?;
        let expansion = expansion_of(&record, &manifest)?;
        let keys = expansion.keys(record.limit);
        Ok(Dataset { dir: dir.to_path_buf(), record, expansion, keys })
    }

    /// Opens a dataset whose run has finished.
    pub fn open_complete(dir: &Path) -> Result<Dataset, String> {
        let dataset = Dataset::open(dir)?;
        if !dataset.record.complete {
            return Err(format!("{} is not complete: finish it with its gen command first", dir.display()));
        }
        Ok(dataset)
    }

    pub fn spec(&self) -> &DatasetSpec {
        &self.expansion.spec
    }

    /// Scenario folders of one group and split, in index order.
    pub fn scenario_dirs(&self, group: &str, split: Split) -> Vec<PathBuf> {
        self.keys
            .iter()
            .filter(|k| k.group == group && k.split == split)
            .map(|k| scenario_dir(&self.dir, &k.group, split.name(), &k.folder_name()))
            .collect()
    }
}

/// The expansion of the spec a manifest (at `path`) records.
pub fn expansion_of(record: &ManifestRecord, path: &Path) -> Result<Expansion, String> {
    let spec: DatasetSpec = serde_json::from_value(record.spec.clone())
        .map_err(|e| format!("{}: the spec in it is unreadable: {e}", path.display()))?;
    Expansion::new(spec, Arc::new(CityMap::default()))
        .map_err(|e| format!("{}: the spec in it is invalid: {e}", path.display()))
}

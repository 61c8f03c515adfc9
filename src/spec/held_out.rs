//! `held_out`: what val and test draw differently from train (their own
//! map, graph shape, car count or confounder ranges), so that a split tests
//! generalisation.

use super::*;

/// A split's own sections, in place of the dataset's: a map (towns train
/// never sees), a graph shape, a car count, and (city world) confounder
/// ranges.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeldOut {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub map: Option<MapSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub graph: Option<GraphSpec>,
    /// Cars per scenario in every group, in place of the group's own count;
    /// each group keeps its edge proportion (edges = round(proportion x
    /// cars / 2)) and its folder name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cars: Option<u32>,
    /// In place of `city.confounders`: each scenario draws the same
    /// exogenous numbers as without it, read through these distributions.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub confounders: Option<ConfounderSpec>,
}

impl HeldOut {
    /// The names of the sections it holds out (`map`, `graph`, `cars`, `confounders`).
    pub fn sections(&self) -> Vec<&'static str> {
        let mut names = Vec::new();
        if self.map.is_some() {
            names.push("map");
        }
        if self.graph.is_some() {
            names.push("graph");
        }
        if self.cars.is_some() {
            names.push("cars");
        }
        if self.confounders.is_some() {
            names.push("confounders");
        }
        names
    }
}

/// The held-out sections of val and test (train is what they are held out
/// from, so it has none).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeldOutSplits {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub val: Option<HeldOut>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub test: Option<HeldOut>,
}

impl HeldOutSplits {
    pub fn is_empty(&self) -> bool {
        self.val.is_none() && self.test.is_none()
    }

    /// The sections `split` holds out, if any.
    pub fn of(&self, split: Split) -> Option<&HeldOut> {
        match split {
            Split::Train => None,
            Split::Val => self.val.as_ref(),
            Split::Test => self.test.as_ref(),
        }
    }
}

/// `error` about a field of `held_out.<split>`, named as the spec names it.
pub(super) fn held_out_field(split: Split, error: SpecError) -> SpecError {
    SpecError::new(format!("held_out.{}.{}", split.name(), error.field), error.message)
}

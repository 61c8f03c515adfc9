//! Who may enter a junction when: traffic lights, a priority road with
//! give-way lines on the other, or stop lines on every approach. The map
//! holds each junction's control and the order of right of way between its
//! movements; perception applies it.

use serde::{Deserialize, Serialize};

/// How a junction decides who goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum JunctionControl {
    /// Traffic lights on every approach (the original's junctions).
    #[default]
    Signals,
    /// No lights: the through road has priority. At a T-junction the bar
    /// is the through road; at a crossing the east-west road. Drivers on
    /// the other road give way at their line to cars on it, and drivers
    /// turning left give way to oncoming traffic.
    Priority,
    /// No lights: every driver stops at its line, then goes when no car
    /// waiting at a line it must give way to, and none crossing its path.
    AllWayStop,
    /// No lights and no priority road: every driver gives way to traffic
    /// coming from its right, and a driver turning left also to oncoming
    /// traffic (German *rechts vor links*, SUMO's `right_before_left`).
    RightBeforeLeft,
}

impl JunctionControl {
    /// The spec's and the files' word for it.
    pub fn name(self) -> &'static str {
        match self {
            JunctionControl::Signals => "signals",
            JunctionControl::Priority => "priority",
            JunctionControl::AllWayStop => "all_way_stop",
            JunctionControl::RightBeforeLeft => "right_before_left",
        }
    }

    /// Every control, in the order the spec's errors list them.
    pub const ALL: [JunctionControl; 4] = [
        JunctionControl::Signals,
        JunctionControl::Priority,
        JunctionControl::AllWayStop,
        JunctionControl::RightBeforeLeft,
    ];
}

/// Which pair of opposite approaches a junction's priority road uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    /// Approaches E and W.
    EastWest,
    /// Approaches N and S.
    NorthSouth,
}

impl Axis {
    /// Whether traffic from `approach` ('N', 'E', 'S' or 'W') drives on this axis.
    pub fn holds(self, approach: char) -> bool {
        match self {
            Axis::EastWest => approach == 'E' || approach == 'W',
            Axis::NorthSouth => approach == 'N' || approach == 'S',
        }
    }

    /// The priority road of a junction with `approaches`: the axis with both
    /// arms (a T's bar), east-west when both or neither have.
    pub fn major(approaches: &std::collections::BTreeSet<char>) -> Axis {
        let both = |a: char, b: char| approaches.contains(&a) && approaches.contains(&b);
        if both('N', 'S') && !both('E', 'W') {
            Axis::NorthSouth
        } else {
            Axis::EastWest
        }
    }
}

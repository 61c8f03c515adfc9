"""Types of the Rust extension module; the documented API is in causalcity/__init__.py."""

from typing import Any, Dict, List, Optional, Tuple

class InputError(ValueError):
    """Bad input: a spec, scenario or intervention file, or a key."""

class GenerationError(RuntimeError):
    """A failure while working (a full disk, a failed write)."""

MAX_THREADS: int

class Array:
    """Values owned by Rust that numpy views without copying."""

    @property
    def __array_interface__(self) -> Dict[str, Any]: ...

class Spec:
    @staticmethod
    def load(path: str) -> "Spec": ...
    @staticmethod
    def from_json(
        text: str, origin: str, path: Optional[str] = None, networks: Optional[str] = None, written: bool = False
    ) -> "Spec": ...
    @property
    def name(self) -> str: ...
    @property
    def world(self) -> str: ...
    @property
    def seed(self) -> int: ...
    @property
    def frames(self) -> int: ...
    @property
    def frame_interval(self) -> float: ...
    @property
    def image_size(self) -> Tuple[int, int]: ...
    @property
    def groups(self) -> List[str]: ...
    @property
    def splits(self) -> List[Tuple[str, int]]: ...
    @property
    def json(self) -> str: ...
    @property
    def sha256(self) -> str: ...
    @property
    def path(self) -> Optional[str]: ...
    @property
    def networks(self) -> Optional[str]: ...
    def keys(self, split: Optional[str] = None, limit: Optional[int] = None) -> List[Tuple[str, str, int]]: ...
    def map_json(self, town: Optional[str] = None) -> str: ...

def simulate(
    spec: Spec, group: str, split: str, index: int, images: bool = False, effects: bool = True
) -> Dict[str, Any]: ...
def read_scenario(dir: str) -> Dict[str, Any]: ...
def check_pair(
    dir: str, group: str, split: str, index: int, spec: Optional[Spec] = None, kinds: Optional[List[str]] = None
) -> None: ...
def read_frames(dir: str, kind: str, frames: int, start: int, end: int, width: int, height: int) -> Array: ...
class Prefetch:
    def __init__(
        self,
        spec: Spec,
        keys: List[Tuple[str, str, int]],
        images: bool = False,
        effects: bool = True,
        threads: Optional[int] = None,
        ahead: Optional[int] = None,
    ) -> None: ...
    def __iter__(self) -> "Prefetch": ...
    def __next__(self) -> Dict[str, Any]: ...

def counterfactual(
    scenario_text: str,
    scenario_origin: str,
    intervention_text: Optional[str] = None,
    intervention_origin: Optional[str] = None,
    images: bool = False,
) -> List[Dict[str, Any]]: ...
def generate(
    spec: Spec,
    out: Optional[str],
    limit: Optional[int] = None,
    threads: Optional[int] = None,
    images: bool = True,
    annotations: bool = False,
    effects: bool = True,
    shard: Optional[str] = None,
    force: bool = False,
    fsync: bool = False,
    progress: bool = True,
    force_space: bool = False,
    lights: str = "changes",
    scenarios_per_tar: Optional[int] = None,
) -> str: ...
def evaluate(
    dataset: str,
    predictions: str,
    graphs: List[str],
    history: int,
    threshold: Optional[float] = None,
    csv: Optional[str] = None,
    per_scenario: Optional[str] = None,
) -> Tuple[str, str, str]: ...
def claim_output(path: str, inputs: List[Tuple[str, str]] = ..., writes: str = ...) -> None: ...
def refuse_links_below(root: str, paths: List[str]) -> None: ...
def write_output(path: str, data: bytes) -> None: ...

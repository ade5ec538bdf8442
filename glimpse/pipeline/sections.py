"""Which config dataclass owns each pipeline.yaml section (tests check both ways:
every field has an entry, every entry a field). The priors' sections come from the prior
registry (glimpse/prior/__init__.py), each prior naming its own."""

from __future__ import annotations

from glimpse.background.config import BackgroundConfig
from glimpse.batch.config import BatchConfig
from glimpse.body.config import BodyConfig
from glimpse.compute import ComputeConfig
from glimpse.crops.config import CropsConfig
from glimpse.eval.config import EvalConfig
from glimpse.fit.config import FitConfig
from glimpse.importers.config import ImportConfig
from glimpse.ingest.config import IngestConfig
from glimpse.joint.config import JointConfig
from glimpse.masks.config import MasksConfig
from glimpse.prior import prior_sections
from glimpse.prior.config import PriorConfig
from glimpse.render.config import RenderConfig
from glimpse.report.config import ReportConfig
from glimpse.sfm.config import CamerasConfig
from glimpse.view.config import ViewConfig

SECTION_CONFIGS: dict[str, type] = {
    "compute": ComputeConfig,
    "body": BodyConfig,
    "render": RenderConfig,
    "prior": PriorConfig,
    **prior_sections(),
    "report": ReportConfig,
    "view": ViewConfig,
    "batch": BatchConfig,
    "import": ImportConfig,
    "ingest": IngestConfig,
    "01_sfm": CamerasConfig,
    "02_smpl_fit": FitConfig,
    "03_masks": MasksConfig,
    "04_bg_pretrain": BackgroundConfig,
    "05_textual_inversion": CropsConfig,
    "06_joint_opt": JointConfig,
    "07_eval": EvalConfig,
}

"""The public names of hdlabels (docs/api.md): imported on first use (``hdcore.exports``)."""

from hdlabels._version import __version__ as __version__
from hdlabels.alhat import HazardMaps as HazardMaps
from hdlabels.alhat import hazard_maps as hazard_maps
from hdlabels.alhat import safety_probability as safety_probability
from hdlabels.errors import HdLabelsError as HdLabelsError
from hdlabels.grid import grid_points as grid_points
from hdlabels.labeling import LabelSummary as LabelSummary
from hdlabels.labeling import label_dataset as label_dataset
from hdlabels.lander import Lander as Lander
from hdlabels.mosaic_dataset import MosaicSettings as MosaicSettings
from hdlabels.mosaic_dataset import MosaicSummary as MosaicSummary
from hdlabels.mosaic_dataset import mosaic_dataset as mosaic_dataset
from hdlabels.settings import LabelSettings as LabelSettings
from hdlabels.store import DemSpec as DemSpec
from hdlabels.store import LabeledScan as LabeledScan
from hdlabels.store import LabelingEntry as LabelingEntry
from hdlabels.store import LabelShardEntry as LabelShardEntry
from hdlabels.store import LabelShardReader as LabelShardReader
from hdlabels.store import find_labeling as find_labeling
from hdlabels.store import iter_labeled_scans as iter_labeled_scans
from hdlabels.store import open_label_shard as open_label_shard

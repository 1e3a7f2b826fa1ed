"""The paper's numbers for the network, its training and its evaluation, each with its source.

"Paper" is Tomita et al., "Bayesian Deep Learning for Segmentation for Autonomous Safe Planetary
Landing"; "Kendall 2015" is Kendall, Badrinarayanan and Cipolla, "Bayesian SegNet"
(arXiv:1511.02680); full references in docs/references.md.
"""

# --- classes and labels -------------------------------------------------------------------------
N_CLASSES = 2  # paper, "Bayesian Deep Learning for Segmentation": C = {Safe, Unsafe}
IN_CHANNELS = 1  # paper, "Implementation Details": the input is one DEM (heights)
CLASS_UNSAFE = 0  # project label convention (hdlabels): 0 unsafe
CLASS_SAFE = 1  # project label convention (hdlabels): 1 safe
IGNORE_INDEX = 255  # project label convention: invalid (border) pixels, ignored in loss and metrics

# --- architecture -------------------------------------------------------------------------------
# VGG16 encoder blocks (Kendall 2015, Sec. 3; Badrinarayanan et al. 2017): 13 conv3x3-BN-ReLU layers.
ENCODER_CHANNELS: tuple[tuple[int, ...], ...] = (
    (64, 64),
    (128, 128),
    (256, 256, 256),
    (512, 512, 512),
    (512, 512, 512),
)
DROPOUT_P = 0.5  # paper, "Implementation Details" (following Kendall 2015)
# Kendall 2015, Sec. 4 ("Central Enc-Dec"): dropout after the deepest three encoder units and at the
# end of the deepest three decoder units (pools 3-5 and decoders 5-3 of the five-block SegNet).
DROPOUT_UNITS = 3
SIZE_MULTIPLE_PX = 32  # 2**5: five 2x2 max-pooling stages (Kendall 2015)
# Counted from the architecture (Kendall 2015): parameters at width 1.0, 1 input channel, 2 classes
# (13 encoder + 12 decoder conv3x3-BN-ReLU layers and a final conv3x3 64 -> 2 with bias, no BN).
PARAMETER_COUNT_FULL_WIDTH = 29_443_010

# --- training (paper, "Implementation Details") -------------------------------------------------
INPUT_SIZE_PX = 512  # DEMs upsampled bilinearly from 100x100 to 512x512
DEM_SIZE_PX = 100  # 100x100 DEMs at 1 m/pixel
BATCH_SIZE = 8
LEARNING_RATE = 1e-4
MOMENTUM = 0.9
EPOCHS = 10_000  # "trained for 10^4 epochs" (about 2 days on an RTX 2070 SUPER)
SPLIT_FRACTIONS = (0.8, 0.1, 0.1)  # 800 / 100 / 100 of 1000 DEMs, random
TRAIN_SIGMA_M = 0.0167  # S-167: the network is trained at 1.67 cm range noise (1-sigma)

# --- inference and evaluation (paper, "Implementation Details", "Uncertainty-aware Safety Map") --
MC_SAMPLES = 8  # M = 8 MC-dropout samples
THRESHOLD_SPEC = "mean"  # H_t = mean predictive entropy over the S-167 validation set
QUANTILE_SWEEP = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)  # paper, "Effect of Varying the Uncertainty Threshold"

# --- the landing table (hdnet.landing) ---------------------------------------------------------------
# hd choice: the navigation dispersions every landing table reports, metres 1-sigma per horizontal
# axis: perfect knowledge, a good terrain-relative navigation (about 1 m) and a coarse one (3 m).
NAV_SIGMAS_M: tuple[float, ...] = (0.0, 1.0, 3.0)
# hd choice: touchdowns per scene; the Monte Carlo's own spread per scene is at most 0.5/sqrt(1000)
# = 0.016, far below the spread between scenes that the interval carries.
TOUCHDOWNS = 1000

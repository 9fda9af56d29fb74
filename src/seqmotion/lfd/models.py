"""``seqmotion.lfd.models``: the networks and the policy, now in :mod:`seqmotion.lfd.policy` (this name stays
importable): :mod:`~seqmotion.lfd.policy.networks` (networks, typed configs) and
:mod:`~seqmotion.lfd.policy.policy` (:class:`PushingPolicy`).
"""

from __future__ import annotations

from .policy.networks import (
    ARM_JOINTS as ARM_JOINTS,
)
from .policy.networks import (
    FEATURES as FEATURES,
)
from .policy.networks import (
    MASTER as MASTER,
)
from .policy.networks import (
    MOTION_DIM as MOTION_DIM,
)
from .policy.networks import (
    POSE_REACH_OFFSET as POSE_REACH_OFFSET,
)
from .policy.networks import (
    PRESETS as PRESETS,
)
from .policy.networks import (
    READOUTS as READOUTS,
)
from .policy.networks import (
    SLAVE as SLAVE,
)
from .policy.networks import (
    STATE_DIM as STATE_DIM,
)
from .policy.networks import (
    VARIABLES as VARIABLES,
)
from .policy.networks import (
    CNNConfig as CNNConfig,
)
from .policy.networks import (
    CommandDecoder as CommandDecoder,
)
from .policy.networks import (
    ImageEncoder as ImageEncoder,
)
from .policy.networks import (
    MotionEncoder as MotionEncoder,
)
from .policy.networks import (
    MotionScaler as MotionScaler,
)
from .policy.networks import (
    PoseNet as PoseNet,
)
from .policy.networks import (
    PoseNetConfig as PoseNetConfig,
)
from .policy.networks import (
    SeqAE as SeqAE,
)
from .policy.networks import (
    SeqAEConfig as SeqAEConfig,
)
from .policy.networks import (
    check_images as check_images,
)
from .policy.networks import (
    check_motions as check_motions,
)
from .policy.networks import (
    master_columns as master_columns,
)
from .policy.networks import (
    motion_dim as motion_dim,
)
from .policy.networks import (
    motion_loss as motion_loss,
)
from .policy.networks import (
    object_features as object_features,
)
from .policy.networks import (
    object_yaw as object_yaw,
)
from .policy.networks import (
    preset as preset,
)
from .policy.networks import (
    slave_columns as slave_columns,
)
from .policy.networks import (
    state_dim as state_dim,
)
from .policy.policy import (
    CNN_TARGET_TEXT as CNN_TARGET_TEXT,
)
from .policy.policy import (
    KINDS as KINDS,
)
from .policy.policy import (
    DecoderSource as DecoderSource,
)
from .policy.policy import (
    FeedbackSource as FeedbackSource,
)
from .policy.policy import (
    PolicyConfig as PolicyConfig,
)
from .policy.policy import (
    PushingPolicy as PushingPolicy,
)
from .policy.policy import (
    require_arm as require_arm,
)

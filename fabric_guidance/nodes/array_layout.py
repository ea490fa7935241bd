"""The layout every per-channel (or per-field) Float64MultiArray of the package carries, so that
a reader of the topic or of a bag sees which value is which (docs/interfaces.md, "Array
labels"): one dimension, as std_msgs/MultiArrayLayout describes a 1-D array (size and stride
the number of values), whose label names the values in data order, comma-separated.
"""
from __future__ import annotations

from typing import Sequence

from std_msgs.msg import MultiArrayDimension, MultiArrayLayout

from ..core.channels import layout_label


def named_layout(names: Sequence[str]) -> MultiArrayLayout:
    """The layout of an array of `names`. A node builds it once and passes it to each message
    it builds: the layout never changes, so a sample costs no layout work."""
    n = len(names)
    return MultiArrayLayout(dim=[MultiArrayDimension(label=layout_label(names), size=n, stride=n)],
                            data_offset=0)

"""The operator's Foxglove layout, config/foxglove/fabric_guidance.json (docs/operator_views.md),
generated from the interface table and the channel map so that its topics and its plotted
channels' names and indices cannot drift from the code: test/test_operator_views.py fails when
the committed file differs from foxglove_json().

    python -m fabric_guidance.lab.views --foxglove [CHANNEL_MAP]   # print it (default: the package's map)
    python -m fabric_guidance.lab.views --foxglove --namespace suit_a   # the layout of a namespaced graph

Foxglove's Plot panel names a series by its `label` setting, or by index when it expands an
array; it does not read a MultiArray's layout label. So each channel is one series
`/pressure_command.data[i]` labelled with the channel map's name for index i.

The file is a layout as Foxglove's "Import from file..." reads it: `configById` (panel id
"<type>!<name>" -> its settings), the split tree `layout`, `globalVariables`, `userNodes`,
`playbackConfig`. Topic names are absolute, in the root namespace as in a bag, or in the
namespace of one suit's graph (`--namespace`; /diagnostics stays global, its statuses named by
node and device).
"""
from __future__ import annotations

import json
from pathlib import Path
import sys
from typing import Sequence

from .. import interface
from ..core.channels import ChannelMap
from ..paths import config_path

#: Where the generated layout is committed (under config/).
FOXGLOVE_LAYOUT = 'foxglove/fabric_guidance.json'

THREE_D_PANEL = '3D!immersive'
COMMAND_PANEL = 'Plot!pressure_command'
MEASURED_PANEL = 'Plot!measured_pressure'
DIAGNOSTICS_PANEL = 'DiagnosticSummary!diagnostics'
ACTIVE_TARGET_PANEL = 'RawMessages!active_target'


def absolute(name: str, namespace: str = '') -> str:
    """A topic of the interface as the views name it: absolute, in `namespace` (the root: '')."""
    return interface.full_name(name, namespace)


def _plot(topic: str, channels: Sequence[str], title: str) -> dict:
    return {
        'foxglovePanelTitle': title,
        'paths': [{'value': f'{topic}.data[{i}]', 'label': name, 'enabled': True,
                   'timestampMethod': 'receiveTime'}          # the arrays have no header stamp
                  for i, name in enumerate(channels)],
        'minYValue': 0,
        'showLegend': True,
        'legendDisplay': 'left',
        'showPlotValuesInLegend': True,
        'isSynced': True,
        'xAxisVal': 'timestamp',
        'sidebarDimension': 160,
    }


def foxglove_layout(channels: Sequence[str], namespace: str = '') -> dict:
    """The layout: the immersive scene (targets, gaze ray, head pose) beside the commanded and
    the measured pressure of every channel by name, /diagnostics and the active target."""
    def absolute(name):
        return interface.full_name(name, namespace)
    frame = interface.IMMERSIVE_FRAME
    three_d = {
        'foxglovePanelTitle': f'gaze, head pose and targets in {frame}',
        'followTf': frame,
        'followMode': 'follow-pose',
        'scene': {},
        'transforms': {},
        'topics': {
            absolute(interface.TARGET_MARKERS): {'visible': True},
            # gaze's x axis is the ray (interface.py): an arrow along x, 2 m long like the targets' distance.
            absolute(interface.GAZE): {'visible': True, 'type': 'arrow', 'arrowScale': [2.0, 0.02, 0.04],
                                       'color': '#00c8ff'},
            absolute(interface.HEAD_POSE): {'visible': True, 'type': 'axis', 'axisScale': 0.2},
        },
        'layers': {
            'grid': {'layerId': 'foxglove.Grid', 'instanceId': 'grid', 'label': 'floor grid (0.5 m)',
                     'visible': True, 'frameId': frame, 'size': 6, 'divisions': 12},
        },
        'cameraState': {'perspective': True, 'distance': 4.5, 'phi': 60, 'thetaOffset': 45,
                        'target': [0, 0, 0], 'targetOffset': [1.0, 0.0, 1.2], 'targetOrientation': [0, 0, 0, 1],
                        'fovy': 45, 'near': 0.01, 'far': 5000},
    }
    return {
        'configById': {
            THREE_D_PANEL: three_d,
            COMMAND_PANEL: _plot(absolute(interface.PRESSURE_COMMAND), channels, 'pressure_command by channel [kPa]'),
            MEASURED_PANEL: _plot(absolute(interface.MEASURED_PRESSURE), channels,
                                  'measured_pressure by channel [kPa]'),
            DIAGNOSTICS_PANEL: {'topicToRender': absolute(interface.DIAGNOSTICS), 'minLevel': 0,
                                'pinnedIds': [], 'hardwareIdFilter': '', 'sortByLevel': True},
            ACTIVE_TARGET_PANEL: {'topicPath': absolute(interface.ACTIVE_TARGET)},
        },
        'globalVariables': {},
        'userNodes': {},
        'playbackConfig': {'speed': 1},
        'layout': {
            'direction': 'row',
            'first': THREE_D_PANEL,
            'second': {
                'direction': 'column',
                'first': {'direction': 'column', 'first': COMMAND_PANEL, 'second': MEASURED_PANEL},
                'second': {'direction': 'row', 'first': DIAGNOSTICS_PANEL, 'second': ACTIVE_TARGET_PANEL,
                           'splitPercentage': 65},
                'splitPercentage': 75,
            },
            'splitPercentage': 45,
        },
    }


def foxglove_json(channel_map_file: str | Path | None = None, namespace: str = '') -> str:
    """The layout's file text for a channel map (default: the package's), in a namespace."""
    cmap = ChannelMap.load(channel_map_file or config_path('hardware/channel_map.yaml'))
    return json.dumps(foxglove_layout(cmap.channels, namespace), indent=2) + '\n'


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    namespace = ''
    if '--namespace' in argv[:-1]:
        i = argv.index('--namespace')
        namespace = argv[i + 1]
        del argv[i:i + 2]
    if not argv or argv[0] != '--foxglove' or len(argv) > 2:
        print('usage: python -m fabric_guidance.lab.views --foxglove [CHANNEL_MAP] [--namespace NS]', file=sys.stderr)
        return 2
    sys.stdout.write(foxglove_json(argv[1] if len(argv) == 2 else None, namespace))
    return 0


if __name__ == '__main__':
    sys.exit(main())

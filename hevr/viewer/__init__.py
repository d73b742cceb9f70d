"""``hevr.Viewer``: the key holder's notebook viewer of an encrypted volume.

:mod:`hevr.viewer.widget` is the viewer (ipywidgets): its widgets are built in
:mod:`hevr.viewer.controls`, its arguments checked in :mod:`hevr.viewer.checks`, its status line
written in :mod:`hevr.viewer.report`; :mod:`hevr.viewer.drag` is its drag surface (an anywidget
whose pointer events set the camera).
"""

from .widget import Viewer

__all__ = ["Viewer"]

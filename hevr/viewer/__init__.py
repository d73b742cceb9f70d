"""``hevr.Viewer``: the key holder's notebook viewer of an encrypted volume.

:mod:`hevr.viewer.widget` is the viewer (ipywidgets); :mod:`hevr.viewer.drag` its drag surface
(an anywidget whose pointer events set the camera).
"""

from .widget import Viewer

__all__ = ["Viewer"]

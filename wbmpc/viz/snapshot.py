"""A static snapshot of a meshcat scene that a saved notebook can show without its kernel.

:meth:`wbmpc.viz.Viewer.notebook_view` puts the scene's self-contained page
(:meth:`~wbmpc.viz.Viewer.static_html`, several MB: the meshes and meshcat's library) in an
``<iframe src="data:text/html;base64,...">``. Chromium does not load a URL longer than
:data:`CHROMIUM_MAX_URL` (2 MiB): such a frame stays ``about:blank#blocked``, so a reopened notebook shows
no robot in Chrome. :func:`snapshot_iframe` passes the page in the frame's ``srcdoc`` attribute instead,
which has no such limit; :func:`notebook_view` is ``Viewer.notebook_view`` with it.

Either frame is HTML: JupyterLab drops iframes from the outputs of a notebook it does not trust (one saved
on another machine or by ``nbclient``), so there the snapshot does not show; only an image would.
"""

from __future__ import annotations

import html

__all__ = ["CHROMIUM_MAX_URL", "notebook_view", "snapshot_iframe"]

CHROMIUM_MAX_URL = 2 * 1024 * 1024  # characters; Chromium's url::kMaxURLChars


def snapshot_iframe(page: str, height: int = 400, css_class: str = "wbmpc-static-scene") -> str:
    """An ``<iframe>`` showing the HTML ``page`` from its ``srcdoc`` attribute (any size, no server).

    Args:
        page: A self-contained HTML page (e.g. :meth:`wbmpc.viz.Viewer.static_html`).
        height: Height of the frame [px].
        css_class: The frame's class.
    """
    return (
        f'<iframe class="{html.escape(css_class)}" srcdoc="{html.escape(page, quote=True)}" width="100%" '
        f'height="{int(height)}" style="border: 0"></iframe>'
    )


def notebook_view(viewer, height: int = 400, snapshot: bool = True):
    """The live scene of ``viewer`` for a notebook cell, with a static snapshot that Chromium loads.

    The same view as :meth:`wbmpc.viz.Viewer.notebook_view` (the live IFrame on the meshcat server, the folded
    snapshot under it), the snapshot given by :func:`snapshot_iframe`. Make it the cell's last expression.

    Args:
        viewer: An open :class:`wbmpc.viz.Viewer`.
        height: Height of each view [px].
        snapshot: Add the static snapshot.

    Returns:
        An :class:`IPython.display.HTML` object.
    """
    from IPython.display import HTML

    size = f'width="100%" height="{int(height)}" style="border: 0"'
    parts = [f'<iframe class="wbmpc-live-scene" src="{html.escape(viewer.url)}" {size}></iframe>']
    if snapshot:
        parts.append(
            "<details><summary>static snapshot of this scene (saved with the notebook, opens without the "
            f"kernel)</summary>{snapshot_iframe(viewer.static_html(), height)}</details>"
        )
    return HTML(f'<div class="wbmpc-scene">{"".join(parts)}</div>')

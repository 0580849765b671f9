"""demo.view: replay a store's episodes in the browser with viser (`demo view`).

    from demo.view import serve
    viewer = serve("pick.zarr", port=0)   # viewer.url; viewer.set_episode(k); viewer.stop()
"""

from demo.view.app import Viewer, load_scene_model, serve

__all__ = ["Viewer", "load_scene_model", "serve"]

"""Scene sources: each builds a ``SceneData`` and writes it in the one scene format (``synthetic``, ``waymo``)."""

"""The weight set shipped with the project: model files and manifest.json (see recondreamer.foundation.weights)."""

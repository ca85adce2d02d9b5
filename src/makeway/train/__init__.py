"""Training code. Modules here may need the optional extras (``study``: scikit-learn, XGBoost;
``train``: torch); the runtime pipeline never imports this package."""

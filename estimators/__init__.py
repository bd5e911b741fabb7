"""The method's estimators: pure numpy/scipy functions and small classes, no I/O."""

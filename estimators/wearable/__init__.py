"""Wearable mode: shoulder and elbow joint angles from two IMUs (Alizadegan & Behzadipour 2016)."""

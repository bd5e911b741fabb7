"""Offline evaluation against ground truth (simulated sessions, the BROAD recordings); not
part of the service."""

"""Companion-computer side: runs a generated steering solver in the loop over MAVLink."""

"""Bring-up of the stereo tracking graph: process launcher, parameters, DDS profile, demo."""

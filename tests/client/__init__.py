"""Tests of stereocam.client against a real daemon."""

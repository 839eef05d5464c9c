"""swim.cli"""

"""swim.diagnostics"""

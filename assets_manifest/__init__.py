"""assets_manifest"""

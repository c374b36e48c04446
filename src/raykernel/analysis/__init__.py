"""Comparing structures: compare and sweep tables, the calibrated cost model, HTML reports.

    from raykernel.analysis import compare
"""

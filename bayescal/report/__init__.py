"""Reports: figures drawn on their own :class:`matplotlib.figure.Figure` objects (figures), plain
text and Markdown tables (text), and the self-contained HTML/JSON/Markdown report of a fit (html)."""

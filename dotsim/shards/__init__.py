"""`dotsim export`'s WebDataset shards, the streamable form of a dataset (docs/FORMAT.md): the sample
format and its channel codecs (format), the writer (writer: a sealed dataset as shards, resumable) and
the reader (reader: shards by path, pattern or URL, streamed or indexed for random access) side by side.
"""

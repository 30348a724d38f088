"""RGB-D sequences: dataset folders, the synthetic room and recorded bags behind one protocol."""

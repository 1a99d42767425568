"""Score the authors' published ARCF-HC boxes on all of UAV123@10fps, as the paper does."""

from arcf.data import data_root
from arcf.eval import load_dataset, score_folder

published = data_root() / "published_results" / "UAV123_10fps"
score = score_folder(published / "ARCF-HC", published / "groundtruth")  # toolkit convention
print(score.summary())  # precision@20 0.666  AUC 0.473  (123 sequences, ...)

seqs = load_dataset("uav123_10fps")  # or "dtb70", "uavdt", or a folder path
print(len(seqs), "sequences with frames here:", ", ".join(s.name for s in seqs))

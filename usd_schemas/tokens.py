"""Every ``tween:*`` name the project authors or reads, generated from ``tween/schema.usda``
by ``python -m usd_schemas.generate`` (do not edit by hand; a test checks it is current).
"""

API = "TweenAPI"  # the applied API schema
TAKE_VARIANT_SET = "tweenTake"  # the variant set holding the takes of a fill
KEY_TIMES = "tween:keyTimes"
KEYED_JOINTS = "tween:keyedJoints"
MODEL = "tween:model"
MODEL_HASH = "tween:modelHash"
SEED = "tween:seed"
TAKE = "tween:take"
JOB_ID = "tween:jobId"
CREATED_AT = "tween:createdAt"
REVIEW_STATUS = "tween:reviewStatus"
APPROVED_TAKE = "tween:approvedTake"
APPROVED_BY = "tween:approvedBy"
APPROVED_AT = "tween:approvedAt"
APPROVAL_NOTE = "tween:approvalNote"
RETARGET_REFERENCE = "tween:retargetReference"
MISSING_JOINTS = "tween:missingJoints"
KEY_JUMPS = "tween:keyJumps"
TRUST = "tween:trust"
TRUST_WEIGHT = "tween:trustWeight"
TRUST_EVIDENCE = "tween:trustEvidence"
SOURCE_JOINT_NAMES = "tween:sourceJointNames"

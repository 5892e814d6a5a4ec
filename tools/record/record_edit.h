// The recording editor behind `d3d-record VERB` (`d3d record VERB`): trim, merge, recover, cat and
// export a recording (common/recording), as `ros2 bag` and `mcap` users expect of theirs.
//
//   trim IN --out OUT (--from S --to S | --bursts A:B)   a stretch, by seconds from the first
//                                                       message or by bursts in file order
//   merge IN... --out OUT                               several recordings of one probe in
//                                                       log-time order
//   recover IN --out OUT                                the intact chunks of a damaged recording
//                                                       rewritten into a clean one
//   cat IN                                              one line per message: time, topic,
//                                                       bytes, what it holds
//   export IN --bursts-dir DIR                          burst folders (calibration.json,
//                                                       bursts/NNNNNN/frame_K.png + burst.json)
//                                                       that d3d-recon --images reads
//
// Exit codes: 0 done, 1 the output could not be written, 2 a usage error or an input that is no
// readable recording, 3 a damaged input was used as far as it was intact (what was lost on stderr).
#pragma once

#include <string>

namespace d3d {

// Whether `word` (argv[1] of d3d-record) names one of the verbs above.
bool IsRecordEditVerb(const std::string& word);
// Runs verb argv[1] with its options argv[2..]; returns the exit code.
int RunRecordEdit(int argc, char** argv);

}  // namespace d3d

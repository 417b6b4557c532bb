"""Host record: the CPU name numba compiles for, and the model name from /proc/cpuinfo."""

import llvmlite.binding as llvm

from expoctl.host import cpu_model_name, host_cpu, numba_target_cpu


def test_model_name_is_read_from_cpuinfo(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC 7763 64-Core Processor\n"
                    "processor\t: 1\nmodel name\t: AMD EPYC 7763 64-Core Processor\n")
    assert cpu_model_name(info) == "AMD EPYC 7763 64-Core Processor"


def test_model_name_falls_back_when_cpuinfo_is_missing_or_has_none(tmp_path):
    assert cpu_model_name(tmp_path / "absent") != ""
    empty = tmp_path / "cpuinfo"
    empty.write_text("processor\t: 0\nmodel name\t:   \n")
    assert cpu_model_name(empty) != ""


def test_host_cpu_names_numbas_target():
    assert numba_target_cpu() == llvm.get_host_cpu_name() != ""
    assert host_cpu().startswith(numba_target_cpu() + " (") and host_cpu().endswith(")")
